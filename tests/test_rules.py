"""Moment rules against closed forms, a textbook sigma-point transform and
Gauss-Hermite quadrature; Haar rotations against their known distribution."""
import itertools

import numpy as np
import pytest
from numpy.polynomial.hermite_e import hermegauss
from scipy import stats

from adaptfilt.rules import CubatureRule, StochasticIntegrationRule, UnscentedRule, haar_rotations

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)

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


# ------------------------------------------------------ modified unscented form
def textbook_ut_about_centre(g, m, P, kappa):
    """Julier and Uhlmann's modified form written out: Pyy = sum_i W_i (Y_i - Y_0)(Y_i - Y_0)^T."""
    n = len(m)
    S = np.linalg.cholesky((n + kappa) * P)
    X = np.vstack([m, m + S.T, m - S.T])
    W = np.full(2 * n + 1, 0.5 / (n + kappa))
    W[0] = kappa / (n + kappa)
    G = g(X)
    D = G - G[0]
    return W @ G, (W[:, None] * D).T @ D, (W[:, None] * (X - m)).T @ (G - W @ G)


@pytest.mark.parametrize("m,P", [(0.0, 1.0), (1.3, 0.2), (-4.0, 7.5)])
@pytest.mark.parametrize("kappa", [-0.9, -0.5, -0.1])
def test_modified_ut_scalar_square_closed_form(m, P, kappa):
    """g = x^2, n = 1: points m +- s sqrt(P), s^2 = 1 + kappa. About g(m): sum_i W_i D_i^2 =
    4 m^2 P + (1 + kappa) P^2 >= 0; the standard form subtracts (E[g] - g(m))^2 = P^2 and gives
    4 m^2 P + kappa P^2, negative at m = 0."""
    g = lambda X: X * X
    args = (g, np.full((1, 1), m), np.full((1, 1, 1), P), kappa)
    std, mod, auto = (UnscentedRule(form=f).moments(*args) for f in ("standard", "modified", "auto"))
    np.testing.assert_allclose(mod.cov[0, 0, 0], 4 * m * m * P + (1 + kappa) * P * P, rtol=1e-12)
    np.testing.assert_allclose(std.cov[0, 0, 0], 4 * m * m * P + kappa * P * P, rtol=1e-10, atol=1e-14)
    np.testing.assert_array_equal(auto.cov, mod.cov)  # kappa < 0: auto is modified
    assert mod.cov[0, 0, 0] > 0
    if m == 0.0:
        assert std.cov[0, 0, 0] < 0  # what the modified form repairs
    for a in (mod, auto):  # the mean and cross-covariance are the standard ones
        np.testing.assert_array_equal(a.mean, std.mean)
        np.testing.assert_allclose(a.cross, std.cross, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(a.mean[0, 0], m * m + P, rtol=1e-12)


def test_modified_ut_matches_written_out_form_and_is_psd():
    rng = np.random.default_rng(21)
    n = 3
    g_rows = lambda X: np.stack([np.exp(np.sin(X[:, 0])) * X[:, 1], X[:, 2] ** 2 - X[:, 0], np.arctan2(X[:, 2], 3 + X[:, 0])], axis=1)
    g = lambda X: np.stack([np.exp(np.sin(X[0])) * X[1], X[2] ** 2 - X[0], np.arctan2(X[2], 3 + X[0])])
    worst_std = np.inf
    for kappa in (-2.9, -2.5, -1.5, -0.5, 0.0, 2.0):
        for _ in range(20):
            m, P = rng.standard_normal(n) * 2, random_spd(rng, n, rng.uniform(0.5, 5))
            mo = UnscentedRule(form="modified").moments(g, m[:, None], P[:, :, None], kappa)
            zm, Pyy, Pxy = textbook_ut_about_centre(g_rows, m, P, kappa)
            np.testing.assert_allclose(mo.mean[:, 0], zm, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(mo.cov[:, :, 0], Pyy, rtol=1e-9, atol=1e-11)
            np.testing.assert_allclose(mo.cross[:, :, 0], Pxy, rtol=1e-10, atol=1e-11)
            assert np.linalg.eigvalsh(mo.cov[:, :, 0])[0] > -1e-12 * np.abs(Pyy).max()
            worst_std = min(worst_std, np.linalg.eigvalsh(UT.moments(g, m[:, None], P[:, :, None], kappa).cov[:, :, 0])[0])
    assert worst_std < -1e-3  # the standard form does go indefinite on these problems


def test_modified_ut_auto_leaves_nonnegative_kappa_unchanged():
    rng = np.random.default_rng(22)
    n, M = 2, 6
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    g = lambda X: np.stack([np.cos(X[0]) * X[1] ** 2, X[0] * X[1]])
    kappas = np.array([-1.5, -0.5, 0.0, 1.0, 3.0, 20.0])
    std = UT.moments(g, m, P, kappas)
    auto = UnscentedRule(form="auto").moments(g, m, P, kappas)
    mod = UnscentedRule(form="modified").moments(g, m, P, kappas)
    pos = kappas >= 0
    np.testing.assert_array_equal(auto.cov[:, :, pos], std.cov[:, :, pos])  # bit for bit
    np.testing.assert_array_equal(auto.cov[:, :, ~pos], mod.cov[:, :, ~pos])
    for k in (0.0, 2.0):
        np.testing.assert_array_equal(UnscentedRule(form="auto").moments(g, m, P, k).cov, UT.moments(g, m, P, k).cov)
    # modified = standard + (E[g] - g(m))(E[g] - g(m))^T everywhere
    bias = mod.mean - g(m[:, None, :])[:, 0, :]
    np.testing.assert_allclose(mod.cov, std.cov + bias[:, None] * bias[None], rtol=1e-10, atol=1e-12)
    assert np.abs(bias).max() > 1e-3
    with pytest.raises(ValueError, match="form must be one of"):
        UnscentedRule(form="centre")


# ------------------------------------------------ stochastic integration options
def si_moments(rule, g, m, P, n_iter, seed, **kw):
    return rule.moments(g, m, P, n_iter, rng=np.random.default_rng(seed), **kw)


def test_si_degree5_single_draw_exact_to_degree_5():
    """Degree 5 integrates quartics and quintics exactly in every draw: the mean of (c.x)^5 and
    x^T A x (c.x)^2, and the variance of a quadratic; degree 3 gets the variance wrong."""
    rng = np.random.default_rng(30)
    n, M = 4, 100  # one draw per run
    m, P = rng.standard_normal(n) * 0.5, random_spd(rng, n)
    A, c = random_spd(rng, n), rng.standard_normal(n)
    mb, Pb = batch(m, P, M)
    mu, s2 = c @ m, c @ P @ c
    quintic = lambda X: (np.einsum("i,isM->sM", c, X) ** 5)[None]
    E5 = mu**5 + 10 * mu**3 * s2 + 15 * mu * s2**2
    mo5 = si_moments(StochasticIntegrationRule(order=5), quintic, mb, Pb, 1, 0)
    np.testing.assert_allclose(mo5.mean[0], E5, rtol=1e-9)
    var = 2 * np.trace(A @ P @ A @ P) + 4 * m @ A @ P @ A @ m
    mo5 = si_moments(StochasticIntegrationRule(order=5), quad_fn(A), mb, Pb, 1, 1)
    np.testing.assert_allclose(mo5.cov[0, 0], var, rtol=1e-9)
    np.testing.assert_allclose(mo5.cross[:, 0], (2 * P @ A @ m)[:, None] * np.ones(M), rtol=1e-9, atol=1e-12)
    mo3 = si_moments(StochasticIntegrationRule(order=3), quad_fn(A), mb, Pb, 1, 1)
    assert np.abs(mo3.cov[0, 0] / var - 1).max() > 0.1
    # and linear maps, covariance included, in every draw, for orders 3 and 5 (not order 1)
    B = rng.standard_normal((2, n))
    lin = lambda X: np.einsum("ij,jsM->isM", B, X)
    for order in (3, 5):
        mo = si_moments(StochasticIntegrationRule(order=order), lin, mb, Pb, 1, 2)
        np.testing.assert_allclose(mo.cov, np.broadcast_to((B @ P @ B.T)[:, :, None], mo.cov.shape), rtol=1e-10)
        np.testing.assert_allclose(mo.mean, np.broadcast_to((B @ m)[:, None], mo.mean.shape), rtol=1e-12, atol=1e-12)
    mo1 = si_moments(StochasticIntegrationRule(order=1), lin, mb, Pb, 1, 2)
    np.testing.assert_allclose(mo1.mean, np.broadcast_to((B @ m)[:, None], mo1.mean.shape), rtol=1e-12, atol=1e-12)
    assert np.abs(mo1.cov[0, 0] / (B @ P @ B.T)[0, 0] - 1).max() > 0.1


@pytest.mark.parametrize("order,passes", [(5, 1), (5, 2), (3, 2), (1, 1)])
def test_si_orders_and_passes_unbiased(reference, order, passes):
    """Single draws (per pass) of every order are unbiased for the mean and the cross-covariance
    of a non-polynomial integrand (>= 1000 draws against Gauss-Hermite)."""
    mean_ref, _, cross_ref = reference
    M = 20000
    mb, Pb = batch(M0, P0, M)
    mo = si_moments(StochasticIntegrationRule(order=order, passes=passes), g_nonpoly, mb, Pb, 1, 40 + order)
    for est, ref in ((mo.mean, mean_ref), (mo.cross.reshape(4, M), cross_ref.ravel())):
        se = est.std(axis=-1, ddof=1) / np.sqrt(M)
        z = (est.mean(axis=-1) - ref) / se
        assert np.all(np.abs(z) < 4.5), z


def test_si_degree5_more_accurate_than_degree3(reference):
    """The reported effect: one degree-5 draw is about as accurate as ten degree-3 draws here."""
    mean_ref, cov_ref, cross_ref = reference
    M = 4000
    mb, Pb = batch(M0, P0, M)

    def rms(order, n_iter):
        mo = si_moments(StochasticIntegrationRule(order=order), g_nonpoly, mb, Pb, n_iter, 7)
        e = np.concatenate([mo.mean - mean_ref[:, None], (mo.cov - cov_ref[:, :, None]).reshape(4, M)])
        return np.sqrt((e**2).mean())

    assert rms(5, 1) < 1.5 * rms(3, 10)
    assert rms(5, 1) < 0.5 * rms(3, 1)


@pytest.mark.parametrize("order,passes", [(3, 1), (5, 1), (3, 2), (5, 2)])
def test_si_integration_error_is_variance_of_the_averaged_mean(order, passes):
    """mean_var = s^2 / N of the per-draw means. The per-draw means are recovered independently
    from the common random numbers: with the same seed, run j's mean after k draws is I_k, so
    S_k = k I_k - (k - 1) I_{k-1}."""
    rng = np.random.default_rng(31)
    n, M, N = 2, 5, 6
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    rule = StochasticIntegrationRule(order=order, passes=passes, integration_error="full")
    I = np.array([si_moments(rule, g_nonpoly, m, P, k, 9).mean for k in range(1, N + 1)])  # (N, 2, M)
    S = np.array([I[0]] + [k * I[k - 1] - (k - 1) * I[k - 2] for k in range(2, N + 1)])
    D = S - S.mean(axis=0)
    V = np.einsum("kiM,kjM->ijM", D, D) / (N - 1) / N
    full = si_moments(rule, g_nonpoly, m, P, N, 9)
    np.testing.assert_allclose(full.mean_var, V, rtol=1e-7, atol=1e-12 * np.abs(V).max())
    diag = si_moments(StochasticIntegrationRule(order=order, passes=passes, integration_error="diag"), g_nonpoly, m, P, N, 9)
    np.testing.assert_allclose(diag.mean_var, V * np.eye(2)[:, :, None], rtol=1e-7, atol=1e-12 * np.abs(V).max())
    assert np.all(np.diagonal(V) > 0) and np.abs(V[0, 1]).max() > 0
    # the term changes nothing else; N = 1 adds nothing (one draw says nothing about the spread)
    plain = si_moments(StochasticIntegrationRule(order=order, passes=passes), g_nonpoly, m, P, N, 9)
    for name in ("mean", "cov", "cross"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(full, name))
    assert plain.mean_var is None
    np.testing.assert_array_equal(si_moments(rule, g_nonpoly, m, P, 1, 9).mean_var, 0.0)
    # per-run n_iter: each run's term is that of its own count
    its = np.array([1, 2, 6, 3, 6])
    per_run = si_moments(rule, g_nonpoly, m, P, its, 9)
    for r, k in enumerate(its):
        np.testing.assert_allclose(per_run.mean_var[:, :, r], si_moments(rule, g_nonpoly, m, P, int(k), 9).mean_var[:, :, r], rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("order,passes,ie", [(5, 1, False), (5, 2, "diag"), (3, 2, "full"), (1, 1, "diag")])
def test_si_new_variants_per_run_n_iter_use_common_random_numbers(order, passes, ie):
    rng = np.random.default_rng(14)
    n, M = 2, 6
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    rule = StochasticIntegrationRule(order=order, passes=passes, integration_error=ie)
    its = np.array([1, 2, 5, 5, 2, 1])
    per_run = si_moments(rule, g_nonpoly, m, P, its, 7)
    np.testing.assert_array_equal(per_run.n_iter, its * passes)
    for N in (1, 2, 5):
        scalar = si_moments(rule, g_nonpoly, m, P, N, 7)
        sel = its == N
        for name in ("mean", "cov", "cross") + (("mean_var",) if ie else ()):
            np.testing.assert_allclose(getattr(per_run, name)[..., sel], getattr(scalar, name)[..., sel], rtol=1e-12, atol=1e-15)
    assert np.all(si_moments(rule, g_nonpoly, m, P, 1, 7).mean != si_moments(rule, g_nonpoly, m, P, 5, 7).mean)


@pytest.mark.parametrize("order,passes", [(3, 1), (5, 2), (1, 1)])
def test_si_per_run_n_iter_evaluates_only_the_runs_still_iterating(order, passes):
    """With one count per run, a draw's points are made for the runs that still need it: the
    function sees sum_j n_iter_j draws' points (plus the centres), not max(n_iter) * M, and each
    run's moments are bit for bit those of the scalar call with its own count (the subsets are
    laid out as the whole batch, a count held by a single run included)."""
    rng = np.random.default_rng(3)
    n, M = 2, 40
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    its = rng.choice([1, 2, 3, 7], size=M)
    its[5] = 12  # the last draws are this run's alone
    rule = StochasticIntegrationRule(order=order, passes=passes)
    seen = []

    def g(X):
        seen.append(X.shape[1] * X.shape[2])
        return g_nonpoly(X)

    per_run = si_moments(rule, g, m, P, its, 7)
    ppd = rule.points_per_draw(n)
    single = its.max() - np.sort(its)[-2]  # draws of run 5 alone: computed on two copies
    assert sum(seen) == M + passes * ppd * (its.sum() + single)
    assert sum(seen) < M + passes * ppd * its.max() * M / 2
    for N in np.unique(its):
        scalar = si_moments(rule, g_nonpoly, m, P, int(N), 7)
        sel = its == N
        for name in ("mean", "cov", "cross"):
            np.testing.assert_array_equal(getattr(per_run, name)[..., sel], getattr(scalar, name)[..., sel])


@pytest.mark.parametrize("passes", [1, 2])
def test_si_tolerance_stopping(passes):
    """Each run iterates until its estimated error is below tol (between n_min and n_max); a run
    that stopped after k draws equals the fixed-count rule at k (common random numbers)."""
    rng = np.random.default_rng(32)
    n, M = 2, 40
    m = rng.standard_normal((n, M)) + np.array([[5.0], [1.0]])
    P = np.moveaxis(np.stack([random_spd(rng, n, s) for s in np.geomspace(0.01, 3, M)]), 0, -1)
    n_max, n_min, tol = 15, 3, 2e-4
    rule = StochasticIntegrationRule(order=3, passes=passes, integration_error="diag", tol=tol, n_min=n_min)
    mo = si_moments(rule, g_nonpoly, m, P, n_max, 11)
    spent = mo.n_iter
    lo, hi = passes * n_min, passes * n_max
    assert np.all((spent >= lo) & (spent <= hi))
    assert (spent == lo).any() and (spent == hi).any() and ((spent > lo) & (spent < hi)).any(), spent
    # narrow P needs fewer iterations than wide P
    assert spent[: M // 4].mean() < spent[-M // 4 :].mean()
    if passes == 1:
        fixed = {k: si_moments(StochasticIntegrationRule(order=3, integration_error="diag"), g_nonpoly, m, P, k, 11)
                 for k in np.unique(spent)}
        for r, k in enumerate(spent):
            for name in ("mean", "cov", "cross", "mean_var"):
                np.testing.assert_allclose(getattr(mo, name)[..., r], getattr(fixed[k], name)[..., r], rtol=1e-12, atol=1e-300)
    # a huge tolerance stops at max(n_min, 2), a tiny one runs to n_max; n_min wins over n_iter
    big = StochasticIntegrationRule(order=3, passes=passes, tol=1e9, n_min=1)
    np.testing.assert_array_equal(si_moments(big, g_nonpoly, m, P, n_max, 11).n_iter, 2 * passes)
    tiny = StochasticIntegrationRule(order=3, passes=passes, tol=1e-300, n_min=1)
    np.testing.assert_array_equal(si_moments(tiny, g_nonpoly, m, P, n_max, 11).n_iter, n_max * passes)
    floor = StochasticIntegrationRule(order=3, passes=passes, tol=1e9, n_min=8)
    np.testing.assert_array_equal(si_moments(floor, g_nonpoly, m, P, 4, 11).n_iter, 8 * passes)


def test_si_tolerance_stops_where_the_error_estimate_crosses_tol():
    """passes=1 watches the mean, Pzz and Pxz: the stopped count k is the first k >= 2 with
    every element-wise variance norm <= tol, recomputed from fixed-count runs."""
    rng = np.random.default_rng(33)
    n, M = 2, 12
    m, P = rng.standard_normal((n, M)) + np.array([[5.0], [1.0]]), np.moveaxis(np.stack([random_spd(rng, n, 0.5) for _ in range(M)]), 0, -1)
    tol, n_max = 1e-3, 20
    mo = si_moments(StochasticIntegrationRule(order=3, integration_error="diag", tol=tol), g_nonpoly, m, P, n_max, 5)
    # the per-draw sums, recovered from fixed counts: S_k = k I_k - (k-1) I_{k-1} for the mean
    # and likewise for the averaged second moments EDD and EXD (about g0 = g(m))
    g0 = g_nonpoly(m[:, None, :])[:, 0, :]
    fixed = [si_moments(StochasticIntegrationRule(order=3), g_nonpoly, m, P, k, 5) for k in range(1, n_max + 1)]
    ED = np.array([f.mean - g0 for f in fixed])
    EDD = np.array([f.cov + ED[k][:, None] * ED[k][None] for k, f in enumerate(fixed)])
    EXD = np.array([f.cross for f in fixed])
    for r in range(M):
        expected = n_max
        for k in range(2, n_max + 1):
            norms = []
            for A in (ED, EDD, EXD):
                S = np.array([A[0][..., r]] + [j * A[j - 1][..., r] - (j - 1) * A[j - 2][..., r] for j in range(2, k + 1)])
                V = S.var(axis=0, ddof=1) / k
                norms.append(np.sqrt((V**2).sum()))
            if max(norms) <= tol:
                expected = k
                break
        assert mo.n_iter[r] == expected, (r, mo.n_iter[r], expected)
    assert len(set(mo.n_iter.tolist())) > 1


def test_si_tiled_call_shares_draws_between_tiles():
    """tile = G: a call on G copies of M runs gives run j of copy g exactly what an untiled call
    of the M runs with the same Generator and copy g's n_iter gives it."""
    rng = np.random.default_rng(34)
    n, M, G = 2, 5, 3
    m, P = rng.standard_normal((n, M)), np.moveaxis(np.stack([random_spd(rng, n) for _ in range(M)]), 0, -1)
    tile = lambda a: np.concatenate([a] * G, axis=-1)
    grid = np.array([1.0, 3.0, 6.0])
    theta = np.repeat(grid, M)
    for rule in (SI, StochasticIntegrationRule(order=5, passes=2, integration_error="diag"),
                 StochasticIntegrationRule(order=3, integration_error="full", tol=1e-3, n_min=2)):
        tiled = si_moments(rule, g_nonpoly, tile(m), tile(P), theta, 8, tile=G)
        plain = si_moments(rule, g_nonpoly, tile(m), tile(P), theta, 8)  # tile = 1: independent draws
        for gi, th in enumerate(grid):
            one = si_moments(rule, g_nonpoly, m, P, th, 8)
            sl = slice(gi * M, (gi + 1) * M)
            for name in ("mean", "cov", "cross", "mean_var", "n_iter"):
                a, b = getattr(tiled, name), getattr(one, name)
                if b is not None:
                    np.testing.assert_allclose(a[..., sl], b, rtol=1e-12, atol=1e-300, err_msg=name)
            if gi:
                assert np.all(plain.mean[:, sl] != tiled.mean[:, sl])
    # tile = 1 is the untiled rule, bit for bit
    np.testing.assert_array_equal(si_moments(SI, g_nonpoly, m, P, 4, 8, tile=1).cov, si_moments(SI, g_nonpoly, m, P, 4, 8).cov)
    for bad, msg in ((4, "must divide the number of runs"), (0, "positive integer"), (1.5, "positive integer")):
        with pytest.raises(ValueError, match=msg):
            si_moments(SI, g_nonpoly, tile(m), tile(P), 2, 8, tile=bad)


def test_si_option_validation_and_counts():
    for kw, msg in (({"order": 4}, "order must be one of"), ({"passes": 3}, "passes must be 1 or 2"),
                    ({"integration_error": "yes"}, "integration_error must be"), ({"tol": 0.0}, "tol must be"),
                    ({"tol": -1.0}, "tol must be"), ({"n_min": 0}, "n_min must be")):
        with pytest.raises(ValueError, match=msg):
            StochasticIntegrationRule(**kw)
    assert StochasticIntegrationRule(order=5).points_per_draw(4) == 60
    assert StochasticIntegrationRule(order=5).points_per_draw(1) == 8
    assert StochasticIntegrationRule(order=1).points_per_draw(4) == 2
    np.testing.assert_array_equal(StochasticIntegrationRule(order=5, passes=2).n_points(4, np.array([1, 10])), [121, 1201])
    np.testing.assert_array_equal(StochasticIntegrationRule(tol=1e-3, n_min=5).n_points(4, 2), 41)
    mb, Pb = batch(M0, P0, 3)

    class NoSeedSequence:  # a Generator without spawn
        def __getattr__(self, name):
            return getattr(np.random.default_rng(0), name)

        spawn = None

    with pytest.raises(ValueError, match="passes=2 needs a numpy Generator with a SeedSequence"):
        StochasticIntegrationRule(passes=2).moments(g_nonpoly, mb, Pb, 2, rng=NoSeedSequence())


@pytest.mark.parametrize("order", [1, 3, 5])
def test_si_integration_error_vanishes_for_linear_maps(order):
    """Every draw of every order integrates the mean of a linear map exactly (points in +- pairs),
    so the per-draw means agree and V = 0 to round-off; order 1's covariance is still random, so
    the zero V says nothing about the covariance's error."""
    rng = np.random.default_rng(35)
    n, M = 3, 50
    m, P = rng.standard_normal(n), random_spd(rng, n)
    B, b = rng.standard_normal((2, n)), rng.standard_normal(2)
    lin = lambda X: np.einsum("ij,jsM->isM", B, X) + b[:, None, None]
    mo = si_moments(StochasticIntegrationRule(order=order, integration_error="full"), lin, *batch(m, P, M), 4, 3)
    assert np.abs(mo.mean_var).max() < 1e-24 * np.abs(B @ P @ B.T).max()
    nonlin = si_moments(StochasticIntegrationRule(order=order, integration_error="full"), g_nonpoly, *batch(M0, P0, M), 4, 3)
    assert np.all(np.diagonal(nonlin.mean_var, axis1=0, axis2=1) > 1e-12)
