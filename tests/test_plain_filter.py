"""The plain one-run Algorithm 1 that chapter 2 shows (adaptfilt.course.plain_filter) computes what the
library's batched filters and rules compute: the same sigma points and weights, the same stochastic draws
from the same Generator, the same filtering means and covariances, on UNGM, the bearing-only CTM (with
bearings that cross the +-pi cut) and a linear-Gaussian model (where the Kalman filter is exact)."""
from __future__ import annotations

import numpy as np
import pytest

import adaptfilt as af
from adaptfilt.course import plain_filter as pf
from adaptfilt.rules import StochasticIntegrationRule, UnscentedRule


def _run_last(g):
    """A function of points ``(S, n) -> (S, ng)`` as a rule calls it: ``(n, S, M) -> (ng, S, M)``."""
    return lambda X: np.moveaxis(g(np.moveaxis(X, 0, -1)), -1, 0)


def _random_gaussian(n: int, rng: np.random.Generator):
    A = rng.normal(size=(n, n))
    return rng.normal(size=n), A @ A.T + 0.5 * np.eye(n)


def _g(X):
    """A bearing-like and a quadratic component: neither is integrated exactly by any rule here."""
    return np.stack([np.arctan2(X[..., -1], X[..., 0] + 5.0), (X**2).sum(-1) / 20], axis=-1)


@pytest.mark.parametrize("n", [1, 2, 4])
@pytest.mark.parametrize("kappa", [-0.5, 0.0, 2.0, 100.0])
def test_unscented_moments_are_the_library_rules(n, kappa):
    m, P = _random_gaussian(n, np.random.default_rng(n))
    mean, cov, cross = pf.weighted_moments(_g, *pf.unscented_points(m, P, kappa))
    mo = UnscentedRule().moments(_run_last(_g), m[:, None], P[:, :, None], kappa)
    np.testing.assert_allclose(mean, mo.mean[:, 0], rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(cov, mo.cov[..., 0], rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(cross, mo.cross[..., 0], rtol=1e-11, atol=1e-13)


def test_unscented_points_give_the_closed_form_pzz_of_ungm():
    """Chapter 2's P^zz(kappa) = (4 m^2 P + kappa P^2) / 400 + R, an independent check of the points."""
    m, P, R = 5.0, 4.0, 0.1
    for kappa in (-0.5, 0.0, 2.0, 20.0):
        _, pzz, _ = pf.weighted_moments(lambda X: X**2 / 20, *pf.unscented_points(np.array([m]), np.array([[P]]),
                                                                                  kappa))
        assert pzz[0, 0] + R == pytest.approx((4 * m**2 * P + kappa * P**2) / 400 + R, rel=1e-13)


@pytest.mark.parametrize("n", [1, 2, 4])
@pytest.mark.parametrize("n_iter", [1, 3, 10])
def test_sir_moments_are_the_library_rule_with_the_same_generator(n, n_iter):
    m, P = _random_gaussian(n, np.random.default_rng(10 + n))
    mean, cov, cross = pf.sir_moments(_g, m, P, n_iter, np.random.default_rng(7))
    mo = StochasticIntegrationRule().moments(_run_last(_g), m[:, None], P[:, :, None], n_iter,
                                             rng=np.random.default_rng(7))
    np.testing.assert_allclose(mean, mo.mean[:, 0], rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(cov, mo.cov[..., 0], rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(cross, mo.cross[..., 0], rtol=1e-11, atol=1e-12)
    # another generator gives other draws: the comparison above could fail
    other = pf.sir_moments(_g, m, P, n_iter, np.random.default_rng(8))
    assert not np.allclose(other[1], cov)


def test_sir_points_are_one_draw_of_an_unbiased_rule():
    """Every draw integrates degree 3 exactly: E[x] = m and Cov[x] = P from one draw, whatever it is."""
    m, P = _random_gaussian(3, np.random.default_rng(3))
    rng = np.random.default_rng(0)
    for _ in range(5):
        X, w = pf.sir_points(m, P, rng)
        mean, cov, _ = pf.weighted_moments(lambda X: X, X, w)
        np.testing.assert_allclose(mean, m, atol=1e-12)
        np.testing.assert_allclose(cov, P, atol=1e-10)
        assert w.sum() == pytest.approx(1.0)


def _filter_all(model, kappa, z):
    out = [pf.gaussian_filter(model, lambda m, P: pf.unscented_points(m, P, kappa), z_r) for z_r in z]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])


@pytest.mark.parametrize("kappa", [2.0, 100.0])
def test_the_plain_ukf_is_the_library_ukf_on_ungm(kappa):
    model = af.models.ungm()
    traj = model.simulate(n_runs=10, n_steps=100, rng=np.random.default_rng(1))
    means, covs = _filter_all(model, kappa, traj.z)
    lib = af.UKF(model, kappa=kappa).run(traj.z)
    # rounding grows over 100 steps of a nonlinear recursion (to about 1e-9 at kappa = 100)
    np.testing.assert_allclose(means, lib.mean, rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(covs, lib.cov, rtol=1e-7, atol=1e-8)
    # kappa matters on UNGM: the library with another kappa is far from the plain filter
    assert np.abs(af.UKF(model, kappa=kappa + 3).run(traj.z).mean - means).max() > 1e-3


def test_the_plain_ukf_is_the_library_ukf_on_the_ctm_across_the_bearing_cut():
    model = af.models.coordinated_turn()
    traj = model.simulate(n_runs=200, rng=np.random.default_rng(0))
    crossing = np.flatnonzero((np.abs(np.diff(traj.z[:, :, 0], axis=1)) > np.pi).any(axis=1))
    assert crossing.size >= 2, "no CTM run whose bearing crosses +-pi: the wrap would go untested"
    z, x = traj.z[crossing[:5]], traj.x[crossing[:5]]
    means, covs = _filter_all(model, 0.0, z)
    lib = af.UKF(model).run(z)
    np.testing.assert_allclose(means, lib.mean, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(covs, lib.cov, rtol=1e-9, atol=1e-8)
    # without the wrap the same filter loses these runs: the test sees the wrap
    unwrapped = af.StateSpaceModel(f=model.f, h=model.h, Q=model.Q, R=model.R, m0=model.m0, P0=model.P0)
    bad, _ = _filter_all(unwrapped, 0.0, z)
    assert np.abs(bad - means).max() > 1.0 and np.isfinite(means).all() and x.shape == means.shape


def test_the_plain_ukf_is_the_kalman_filter_on_a_linear_model():
    lin = af.models.linear_gaussian(F=[[0.9, 0.2], [0.0, 0.8]], H=[[1.0, 0.0], [0.5, 1.0]], Q=[[1.0, 0.0], [0.0, 0.3]],
                                    R=[[0.5, 0.1], [0.1, 0.4]], m0=[0.0, 1.0], P0=[[5.0, 0.0], [0.0, 2.0]], n_steps=40)
    traj = lin.simulate(n_runs=4, rng=np.random.default_rng(2))
    means, covs = _filter_all(lin, 1.0, traj.z)
    kf = af.KalmanFilter(lin).run(traj.z)
    np.testing.assert_allclose(means, kf.mean, rtol=1e-10, atol=1e-11)
    np.testing.assert_allclose(covs, kf.cov, rtol=1e-10, atol=1e-11)


def test_one_sif_update_on_the_ctm_is_the_library_update():
    """The SIF's update at step t draws from Generator([seed, 1, t]) (``GaussianAssumedFilter.rng``): for one
    run the plain rule with that Generator gives the library's update, bearings wrapped."""
    model = af.models.coordinated_turn()
    z = model.simulate(n_runs=3, n_steps=5, rng=np.random.default_rng(4)).z
    for r, t in [(0, 0), (1, 2), (2, 4)]:
        u = af.SIF(model, n_iter=7, seed=3).update(model.m0[None], model.P0[None], z[r:r + 1, t], t)
        z_pred, Pzz, Pxz = pf.sir_moments(lambda X: model.h(X, t + 1), model.m0, model.P0, 7,
                                          np.random.default_rng([3, 1, t]), model.diff_z)
        np.testing.assert_allclose(z_pred, u.z_pred[0], rtol=1e-12)
        np.testing.assert_allclose(Pzz + model.R, u.Pzz[0], rtol=1e-11)
        np.testing.assert_allclose(Pxz, u.Pxz[0], rtol=1e-11, atol=1e-12)
