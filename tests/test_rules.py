"""Moment rules against closed forms, a textbook sigma-point transform and
Gauss-Hermite quadrature; Haar rotations against their known distribution."""
import itertools

import numpy as np
import pytest
from numpy.polynomial.hermite_e import hermegauss
from scipy import stats

from adaptfilt.rules import CubatureRule, StochasticIntegrationRule, UnscentedRule, haar_rotations

UT = UnscentedRule()
SI = StochasticIntegrationRule()


def random_spd(rng, n, scale=1.0):
    G = rng.standard_normal((n, n))
    return scale * (G @ G.T / n + 0.5 * np.eye(n))


def batch(m, P, M):
    """One (m, P) repeated over M runs, run axis last."""
    return np.repeat(np.asarray(m, float)[:, None], M, 1), np.repeat(np.asarray(P, float)[:, :, None], M, 2)


def quad_fn(A):
    """x^T A x, run-last: (n, S, M) -> (1, S, M)."""
    return lambda X: np.einsum("isM,ij,jsM->sM", X, A, X)[None]


def gauss_hermite(g, m, P, order=40):
    """Reference moments of g(x), x ~ N(m, P), by tensor Gauss-Hermite quadrature.

    ``g`` maps (N, n) -> (N, ng). Returns mean (ng,), cov (ng, ng), cross (n, ng).
    """
    n = len(m)
    xi, w = hermegauss(order)
    w = w / np.sqrt(2 * np.pi)
    nodes = np.array(list(itertools.product(xi, repeat=n)))
    weights = np.prod(np.array(list(itertools.product(w, repeat=n))), axis=1)
    X = m + nodes @ np.linalg.cholesky(P).T
    G = g(X)
    mean = weights @ G
    D = G - mean
    return mean, (weights[:, None] * D).T @ D, (weights[:, None] * (X - m)).T @ D


def textbook_ut(g, m, P, kappa):
    """Julier's UT written the textbook way (non-centred), one (m, P)."""
    n = len(m)
    S = np.linalg.cholesky((n + kappa) * P)
    X = np.vstack([m, m + S.T, m - S.T])
    W = np.full(2 * n + 1, 0.5 / (n + kappa))
    W[0] = kappa / (n + kappa)
    G = g(X)
    zm = W @ G
    D = G - zm
    return zm, (W[:, None] * D).T @ D, (W[:, None] * (X - m)).T @ D


# --------------------------------------------------------------------- unscented
KAPPAS = lambda n: [-0.5 * n, -0.2 * n, 0.0, 3.0 - n, 1.0, 10.0, 1e3]


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_ut_quadratic_mean_and_cross_cov_any_kappa(n):
    rng = np.random.default_rng(n)
    M = 6  # each run its own (m, P, kappa)
    A = rng.standard_normal((n, n))
    A = A + A.T
    ms = rng.standard_normal((M, n)) * 3
    Ps = np.stack([random_spd(rng, n, s) for s in rng.uniform(0.1, 10, M)])
    for kappa in KAPPAS(n):
        mo = UT.moments(quad_fn(A), ms.T.copy(), np.moveaxis(Ps, 0, -1).copy(), kappa)
        for r in range(M):
            m, P = ms[r], Ps[r]
            mean = np.trace(A @ P) + m @ A @ m
            cross = 2 * P @ A @ m
            np.testing.assert_allclose(mo.mean[0, r], mean, rtol=1e-10, atol=1e-10 * abs(mean))
            np.testing.assert_allclose(mo.cross[:, 0, r], cross, rtol=1e-9, atol=1e-9 * np.abs(cross).max())


@pytest.mark.parametrize("m,P", [(0.0, 1.0), (1.3, 0.2), (-4.0, 7.5)])
def test_ut_scalar_quadratic_variance_exact_at_n_plus_kappa_3(m, P):
    a, b, c = 0.7, -1.1, 0.3  # g = a x^2 + b x + c
    g = lambda X: a * X * X + b * X + c
    mean = a * (P + m * m) + b * m + c
    var = 2 * a * a * P * P + (2 * a * m + b) ** 2 * P  # Var of a quadratic in a Gaussian
    mo = UT.moments(g, np.full((1, 1), m), np.full((1, 1, 1), P), 2.0)
    np.testing.assert_allclose(mo.mean[0, 0], mean, rtol=1e-12)
    np.testing.assert_allclose(mo.cov[0, 0, 0], var, rtol=1e-12)
    np.testing.assert_allclose(mo.cross[0, 0, 0], (2 * a * m + b) * P, rtol=1e-12, atol=1e-14)
    # at any other kappa the fourth moment (hence the variance) is wrong by a known amount
    for kappa in (0.0, 5.0, -0.5):
        mo = UT.moments(g, np.full((1, 1), m), np.full((1, 1, 1), P), kappa)
        np.testing.assert_allclose(mo.cov[0, 0, 0], var + a * a * P * P * (kappa - 2), rtol=1e-10, atol=1e-12)


def test_ut_variance_of_quadratic_in_n_dims():
    """The UT (kappa = 3 - n) is exact for a quadratic along one Cholesky axis, not for a generic one."""
    rng = np.random.default_rng(7)
    n = 3
    m, P = rng.standard_normal(n), random_spd(rng, n)
    L = np.linalg.cholesky(P)
    u = np.linalg.solve(L.T, np.eye(n)[0])  # L^T A L = e1 e1^T
    for A, exact in ((np.outer(u, u), True), (random_spd(rng, n), False)):
        var = 2 * np.trace(A @ P @ A @ P) + 4 * m @ A @ P @ A @ m
        mo = UT.moments(quad_fn(A), m[:, None], P[:, :, None], 3.0 - n)
        if exact:
            np.testing.assert_allclose(mo.cov[0, 0, 0], var, rtol=1e-10)
        else:
            assert abs(mo.cov[0, 0, 0] - var) > 1e-3 * var


def test_ut_matches_textbook_transform_on_nonlinear_function():
    """The centred, batched arithmetic equals the textbook formulas, negative kappa included."""
    rng = np.random.default_rng(8)
    n = 3

    def g_rows(X):  # (N, n) -> (N, 2)
        return np.stack([np.exp(np.sin(X[:, 0])) * X[:, 1], np.arctan2(X[:, 2], 3 + X[:, 0])], axis=1)

    g = lambda X: np.stack([np.exp(np.sin(X[0])) * X[1], np.arctan2(X[2], 3 + X[0])])
    for kappa in KAPPAS(n):
        m, P = rng.standard_normal(n), random_spd(rng, n)
        mo = UT.moments(g, m[:, None], P[:, :, None], kappa)
        zm, Pzz, Pxz = textbook_ut(g_rows, m, P, kappa)
        np.testing.assert_allclose(mo.mean[:, 0], zm, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(mo.cov[:, :, 0], Pzz, rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(mo.cross[:, :, 0], Pxz, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kappa", [-1.0, 0.0, 2.0, 50.0])
def test_ut_linear_function_exact(kappa):
    rng = np.random.default_rng(9)
    n = 4
    A, b = rng.standard_normal((2, n)), rng.standard_normal(2)
    m, P = rng.standard_normal(n), random_spd(rng, n)
    mo = UT.moments(lambda X: np.einsum("ij,jsM->isM", A, X) + b[:, None, None], m[:, None], P[:, :, None], kappa)
    np.testing.assert_allclose(mo.mean[:, 0], A @ m + b, rtol=1e-12)
    np.testing.assert_allclose(mo.cov[:, :, 0], A @ P @ A.T, rtol=1e-10)
    np.testing.assert_allclose(mo.cross[:, :, 0], P @ A.T, rtol=1e-10)


def test_ut_per_run_kappa_equals_scalar_calls():
    rng = np.random.default_rng(10)
    n, M = 2, 5
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    g = lambda X: np.stack([np.cos(X[0]) * X[1] ** 2])
    kappas = np.array([-1.5, 0.0, 1.0, 3.0, 20.0])
    mo = UT.moments(g, m, P, kappas)
    for r, k in enumerate(kappas):
        one = UT.moments(g, m[:, r : r + 1], P[:, :, r : r + 1], k)
        np.testing.assert_allclose(mo.mean[:, r], one.mean[:, 0], rtol=1e-13)
        np.testing.assert_allclose(mo.cov[:, :, r], one.cov[:, :, 0], rtol=1e-13)
        np.testing.assert_allclose(mo.cross[:, :, r], one.cross[:, :, 0], rtol=1e-13)
    # and kappa matters here (the comparison is not vacuous)
    other = UT.moments(g, m, P, 2.0)
    assert np.all(np.abs(other.cov[0, 0] - mo.cov[0, 0])[kappas != 2.0] > 1e-6)


def test_ut_kappa_validation():
    m, P = batch([0.0, 0.0], np.eye(2), 3)
    g = lambda X: X
    for bad in (-2.0, -3.0, np.array([1.0, -2.5, 0.0])):
        with pytest.raises(ValueError, match=r"kappa must satisfy n \+ kappa > 0"):
            UT.moments(g, m, P, bad)
    with pytest.raises(ValueError, match="kappa must be finite"):
        UT.moments(g, m, P, np.nan)
    assert UT.default_param(1) == 2.0 and UT.default_param(4) == 0.0 and UT.default_param(3) == 0.0
    assert UnscentedRule(default_kappa=-0.5).default_param(2) == -0.5


def test_cubature_rule_is_ut_at_kappa_zero():
    rng = np.random.default_rng(11)
    m, P = rng.standard_normal((3, 1)), random_spd(rng, 3)[:, :, None]
    g = lambda X: np.stack([np.sin(X[0] * X[1]), X[2] ** 3])
    a, b = CubatureRule().moments(g, m, P, CubatureRule().default_param(3)), UT.moments(g, m, P, 0.0)
    np.testing.assert_array_equal(a.cov, b.cov)
    np.testing.assert_array_equal(a.mean, b.mean)
    assert UT.n_points(3, 0.0) == 7


def test_moments_non_pd_covariance_raises():
    from adaptfilt.linalg import NotPositiveDefinite

    m, P = batch([0.0, 0.0], np.eye(2), 4)
    P[:, :, 2] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(NotPositiveDefinite, match=r"run\(s\) 2"):
        UT.moments(lambda X: X, m, P, 1.0)


# ---------------------------------------------------------------------- haar
@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_haar_rotations_orthogonal(n):
    Q = haar_rotations(n, 500, np.random.default_rng(n))
    assert Q.shape == (n, n, 500)
    QtQ = np.einsum("kiM,kjM->ijM", Q, Q)
    np.testing.assert_allclose(QtQ, np.broadcast_to(np.eye(n)[:, :, None], QtQ.shape), atol=1e-12)


@pytest.mark.parametrize("n", [2, 4])
def test_haar_rotations_distribution(n):
    M = 40000
    Q = haar_rotations(n, M, np.random.default_rng(100 + n))
    q = Q[:, 0, :]  # first column: uniform on the sphere
    EqqT = np.einsum("iM,jM->ij", q, q) / M
    np.testing.assert_allclose(EqqT, np.eye(n) / n, atol=5 * np.sqrt(2.0 / (n * n * M)))
    np.testing.assert_allclose(q.mean(axis=1), 0.0, atol=5 / np.sqrt(n * M))
    # E[q_1^4] = 3 / (n (n + 2)) on the unit sphere
    assert abs((q[0] ** 4).mean() - 3 / (n * (n + 2))) < 5 * np.sqrt(1.0 / M) * 0.3
    # the whole matrix: Haar on O(n) has E[tr Q] = 0, E[tr(Q)^2] = 1, and
    # the law of tr(Q) and of Q[1, 0] matches scipy's independent sampler
    tr = np.trace(Q)
    assert abs(tr.mean()) < 5 / np.sqrt(M)
    assert abs((tr**2).mean() - 1.0) < 0.05
    ref = stats.ortho_group.rvs(n, size=M, random_state=1)
    # (rounded: for n = 2 half the mass is an atom at tr = 0, blurred by round-off)
    assert stats.ks_2samp(np.round(tr, 9), np.round(np.trace(ref, axis1=1, axis2=2), 9)).pvalue > 1e-3
    assert stats.ks_2samp(Q[1, 0], ref[:, 1, 0]).pvalue > 1e-3
    # a fixed rotation R does not change the law: (R Q)[0,0] ~ Q[0,0]
    R = stats.ortho_group.rvs(n, random_state=2)
    RQ = np.einsum("ij,jkM->ikM", R, Q)
    assert stats.ks_2samp(RQ[0, 0], Q[0, 0]).pvalue > 1e-3


# --------------------------------------------------------- stochastic integration
def g_nonpoly(X):
    """Run-last (2, S, M) -> (2, S, M): exp(sin x1) and a bearing."""
    return np.stack([np.exp(np.sin(X[0])), np.arctan2(X[1], X[0])])


def g_nonpoly_rows(X):
    return np.stack([np.exp(np.sin(X[:, 0])), np.arctan2(X[:, 1], X[:, 0])], axis=1)


M0, P0 = np.array([5.0, 1.0]), np.array([[0.6, 0.2], [0.2, 0.4]])


@pytest.fixture(scope="module")
def reference():
    return gauss_hermite(g_nonpoly_rows, M0, P0, order=60)


def test_gauss_hermite_reference_is_converged(reference):
    mean2, cov2, cross2 = gauss_hermite(g_nonpoly_rows, M0, P0, order=40)
    np.testing.assert_allclose(reference[0], mean2, atol=1e-10)
    np.testing.assert_allclose(reference[1], cov2, atol=1e-10)
    # sanity: a polynomial is integrated exactly
    mean, _, _ = gauss_hermite(lambda X: (X[:, :1] ** 2), M0, P0, order=5)
    np.testing.assert_allclose(mean, M0[0] ** 2 + P0[0, 0], rtol=1e-13)


def test_si_single_draw_exact_for_degree_3():
    rng = np.random.default_rng(12)
    n, M = 3, 200  # 200 independent draws, one per run
    m, P = rng.standard_normal(n), random_spd(rng, n)
    A = random_spd(rng, n)
    c = rng.standard_normal(n)
    # degree-3 polynomial: x^T A x + (c.x)^3
    g = lambda X: (np.einsum("isM,ij,jsM->sM", X, A, X) + np.einsum("i,isM->sM", c, X) ** 3)[None]
    s2 = c @ P @ c
    mean = np.trace(A @ P) + m @ A @ m + (c @ m) ** 3 + 3 * (c @ m) * s2
    mb, Pb = batch(m, P, M)
    mo = SI.moments(g, mb, Pb, 1, rng=np.random.default_rng(0))
    np.testing.assert_allclose(mo.mean[0], mean, rtol=1e-10)
    # a linear map is exact in every draw, for the covariance too
    B = rng.standard_normal((2, n))
    mo = SI.moments(lambda X: np.einsum("ij,jsM->isM", B, X), mb, Pb, 1, rng=np.random.default_rng(1))
    np.testing.assert_allclose(mo.cov, np.broadcast_to((B @ P @ B.T)[:, :, None], mo.cov.shape), rtol=1e-10)
    np.testing.assert_allclose(mo.cross, np.broadcast_to((P @ B.T)[:, :, None], mo.cross.shape), rtol=1e-10)


def test_si_single_draw_unbiased(reference):
    """Average of many independent single draws -> quadrature (mean and cross-covariance
    are unbiased for any integrand)."""
    mean_ref, _, cross_ref = reference
    M = 40000
    mb, Pb = batch(M0, P0, M)
    mo = SI.moments(g_nonpoly, mb, Pb, 1, rng=np.random.default_rng(13))
    for est, ref in ((mo.mean, mean_ref), (mo.cross.reshape(4, M), cross_ref.ravel())):
        se = est.std(axis=-1, ddof=1) / np.sqrt(M)
        z = (est.mean(axis=-1) - ref) / se
        assert np.all(np.abs(z) < 4.5), z
    # a single draw is far from exact (so the average above is not trivially right)
    assert np.abs(mo.mean[0] - mean_ref[0]).max() > 1e-3


def test_si_converges_like_inverse_sqrt_n(reference):
    mean_ref, cov_ref, cross_ref = reference
    M = 800  # independent repetitions (one per run)
    mb, Pb = batch(M0, P0, M)
    Ns = np.array([1, 4, 16, 64])
    err = []
    for i, N in enumerate(Ns):
        mo = SI.moments(g_nonpoly, mb, Pb, int(N), rng=np.random.default_rng(1000 + i))
        e = np.concatenate(
            [(mo.mean - mean_ref[:, None]), (mo.cov - cov_ref[:, :, None]).reshape(4, M),
             (mo.cross - cross_ref[:, :, None]).reshape(4, M)]
        )
        err.append(np.sqrt((e**2).mean(axis=1)))  # RMS error per quantity
    err = np.array(err)  # (len(Ns), 10)
    slopes = np.polyfit(np.log(Ns), np.log(err), 1)[0]
    assert np.all((slopes > -0.62) & (slopes < -0.38)), slopes
    assert abs(np.median(slopes) + 0.5) < 0.05, slopes
    # and the errors at N = 64 are small in absolute terms
    assert np.all(err[-1] < 0.25 * err[0])


def test_si_per_run_n_iter_uses_common_random_numbers():
    rng = np.random.default_rng(14)
    n, M = 2, 6
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    its = np.array([1, 2, 5, 5, 2, 1])
    per_run = SI.moments(g_nonpoly, m, P, its, rng=np.random.default_rng(7))
    for N in (1, 2, 5):
        scalar = SI.moments(g_nonpoly, m, P, N, rng=np.random.default_rng(7))
        sel = its == N
        np.testing.assert_allclose(per_run.mean[:, sel], scalar.mean[:, sel], rtol=1e-12)
        np.testing.assert_allclose(per_run.cov[:, :, sel], scalar.cov[:, :, sel], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(per_run.cross[:, :, sel], scalar.cross[:, :, sel], rtol=1e-12, atol=1e-15)
    # different counts give different numbers
    a = SI.moments(g_nonpoly, m, P, 1, rng=np.random.default_rng(7))
    b = SI.moments(g_nonpoly, m, P, 5, rng=np.random.default_rng(7))
    assert np.all(a.mean != b.mean)


def test_si_reproducible_and_seed_dependent():
    mb, Pb = batch(M0, P0, 5)
    a = SI.moments(g_nonpoly, mb, Pb, 3, rng=np.random.default_rng(5))
    b = SI.moments(g_nonpoly, mb, Pb, 3, rng=np.random.default_rng(5))
    c = SI.moments(g_nonpoly, mb, Pb, 3, rng=np.random.default_rng(6))
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.cov, b.cov)
    assert np.all(a.mean != c.mean)


def test_si_param_validation():
    mb, Pb = batch(M0, P0, 3)
    for bad in (0, 2.5, -1, np.nan, np.array([1, 0, 2])):
        with pytest.raises(ValueError, match="n_iter must be a positive integer"):
            SI.moments(g_nonpoly, mb, Pb, bad, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="needs a numpy Generator"):
        SI.moments(g_nonpoly, mb, Pb, 2)
    assert SI.default_param(4) == 10.0
    np.testing.assert_array_equal(SI.n_points(4, np.array([1, 10])), [9, 81])
