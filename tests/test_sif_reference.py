"""The SIF against the authors' Python port, Stone Soup 1.9 (``StochasticIntegrationUpdater``,
``StochasticIntegrationPredictor``, ``stochastic_cubature_rule_points``).

Draw for draw: Stone Soup's random sources (``np.random.chisquare``,
``np.random.beta``, ``np.random.randn``, ``scipy.stats.ortho_group``) are
replaced by queues holding the radii and rotations our rule draws from the same
Generator, so both compute from identical points; then the predicted moments
must agree to 1e-10. Statistically: Stone Soup with its own random numbers and
ours over 1000 draws each must agree in distribution.
"""
import numpy as np
import pytest
from scipy import stats

stonesoup = pytest.importorskip("stonesoup")

import stonesoup.functions as ssf  # noqa: E402
from stonesoup.base import Property  # noqa: E402
from stonesoup.models.base import TimeVariantModel  # noqa: E402
from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement  # noqa: E402
from stonesoup.models.transition.nonlinear import GaussianTransitionModel  # noqa: E402
from stonesoup.predictor.kalman import StochasticIntegrationPredictor  # noqa: E402
from stonesoup.types.array import CovarianceMatrix, StateVector, StateVectors  # noqa: E402
from stonesoup.types.prediction import GaussianStatePrediction  # noqa: E402
from stonesoup.types.state import GaussianState  # noqa: E402
from stonesoup.updater.kalman import StochasticIntegrationUpdater  # noqa: E402

import adaptfilt as af  # noqa: E402
from adaptfilt.linalg import wrap_angle  # noqa: E402
from adaptfilt.rules.stochastic import StochasticIntegrationRule, _gram_schmidt, stochastic_rule_points  # noqa: E402

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


# ------------------------------------------------------------- Stone Soup models
class FnMeasurement(NonLinearGaussianMeasurement):
    """A Stone Soup measurement model around a batched ``h(x (..., nx)) -> (..., nz)``."""

    h: object = Property(doc="batched measurement function")

    @property
    def ndim_meas(self):
        return self.noise_covar.shape[0]

    def function(self, state, noise=False, **kwargs):
        X = np.asarray(state.state_vector, dtype=float)
        return StateVectors(np.asarray(self.h(X.T)).T)


class FnTransition(GaussianTransitionModel, TimeVariantModel):
    """A Stone Soup transition model around a batched ``f``."""

    f: object = Property(doc="batched transition function")
    Q: np.ndarray = Property(doc="process noise covariance")

    @property
    def ndim_state(self):
        return self.Q.shape[0]

    def covar(self, **kwargs):
        return CovarianceMatrix(self.Q)

    def function(self, state, noise=False, **kwargs):
        X = np.asarray(state.state_vector, dtype=float)
        return StateVectors(np.asarray(self.f(X.T)).T)


def ss_updater(model, order, n_min, n_max, eps):
    mm = FnMeasurement(h=lambda X: model.h(X, 1), noise_covar=model.R, mapping=tuple(range(model.nx)), ndim_state=model.nx)
    return StochasticIntegrationUpdater(measurement_model=mm, Nmin=n_min, Nmax=n_max, Eps=eps, SIorder=order)


def ss_predictor(model, order, n_min, n_max, eps):
    tm = FnTransition(f=lambda X: model.f(X, 1), Q=model.Q)
    return StochasticIntegrationPredictor(transition_model=tm, Nmin=n_min, Nmax=n_max, Eps=eps, SIorder=order)


def ss_measurement_prediction(updater, x, P):
    pred = updater.predict_measurement(GaussianStatePrediction(StateVector(x), CovarianceMatrix(P)))
    return np.asarray(pred.state_vector, float)[:, 0], np.asarray(pred.covar, float), np.asarray(pred.cross_covar, float)


def ss_state_prediction(predictor, x, P):
    pred = predictor.predict(GaussianState(StateVector(x), CovarianceMatrix(P)))
    return np.asarray(pred.state_vector, float)[:, 0], np.asarray(pred.covar, float)


# ------------------------------------------------------------- our models
def ctm():
    """The paper's bearing-only CTM (linear dynamics: only its update is stochastic)."""
    return af.models.coordinated_turn()


def ct_range_bearing():
    """A second nonlinear model: coordinated turn with the turn rate in the state (nonlinear f),
    range and bearing measured (nz = 2, so the diagonal integration-error term is tested)."""

    def f(x, k):
        px, vx, py, vy, w = np.moveaxis(x, -1, 0)
        s, c = np.sin(w), np.cos(w)
        return np.stack([px + s / w * vx - (1 - c) / w * vy, c * vx - s * vy,
                         py + (1 - c) / w * vx + s / w * vy, s * vx + c * vy, w], axis=-1)

    def h(x, k):
        return np.stack([np.hypot(x[..., 0], x[..., 2]), np.arctan2(x[..., 2], x[..., 0])], axis=-1)

    def residual(a, b):
        d = a - b
        return np.concatenate([d[..., :1], wrap_angle(d[..., 1:])], axis=-1)

    Q = np.diag([0.3, 0.1, 0.3, 0.1, 1e-4])
    return af.StateSpaceModel(f=f, h=h, Q=Q, R=np.diag([4.0, 1e-3]), m0=[60.0, 5.0, 40.0, -3.0, 0.3],
                              P0=np.diag([25.0, 4.0, 25.0, 4.0, 0.01]), residual=residual, name="ct-rb")


# state at which the moments are compared: bearings far from +-pi (Stone Soup averages raw
# angles, we average about the centre's bearing: they agree when nothing wraps)
POINTS = {
    "ctm": (np.array([80.0, 1.0, 30.0, 20.0]), np.diag([30.0, 5.0, 30.0, 5.0]) + 2.0),
    "ct-rb": (np.array([60.0, 5.0, 40.0, -3.0, 0.3]), np.diag([25.0, 4.0, 25.0, 4.0, 0.01])),
}
MODELS = {"ctm": ctm, "ct-rb": ct_range_bearing}


# ------------------------------------------------------------- draw feeding
class Feed:
    """Stone Soup's random sources, answering from a queue of our rule's draws."""

    def __init__(self, order, n, raws):
        self.order, self.n, self.raws = order, n, list(raws)
        self.used = {"Q": 0, "chi2": 0, "beta": 0, "X": 0}

    def _next(self, kind, index):
        i = self.used[kind]
        if i >= len(self.raws):
            raise AssertionError("Stone Soup asked for more draws than fed")
        self.used[kind] += 1
        return self.raws[i][index]

    def chisquare(self, df, size=None):
        assert df == (self.n + 2 if self.order == 3 else 2 * self.n + 7)
        return float(self._next("chi2", 1)[0])

    def beta(self, a, b, size=None):
        assert (a, b) == (self.n + 2, 1.5)
        return float(self._next("beta", 2)[0])

    def randn(self, *shape):
        assert shape == (self.n, 1)
        return self._next("X", 0).reshape(self.n, 1)

    def rvs(self, dim, *args, **kwargs):  # ortho_group.rvs
        assert dim == self.n
        return self._next("Q", 0)[:, :, 0]

    @property
    def draws(self):
        return max(self.used.values())


def feed_stone_soup(monkeypatch, feed):
    monkeypatch.setattr(np.random, "chisquare", feed.chisquare)
    monkeypatch.setattr(np.random, "beta", feed.beta)
    monkeypatch.setattr(np.random, "randn", feed.randn)
    monkeypatch.setattr(ssf, "ortho_group", feed)


def our_draws(order, n, rng, k):
    """Our draws' variates, the rotation orthogonalised (``_draw`` gives its Gaussian matrix)."""
    rule = StochasticIntegrationRule(order=order)
    raws = [rule._draw(n, 1, rng) for _ in range(k)]
    return raws if order == 1 else [(_gram_schmidt(r[0]),) + r[1:] for r in raws]


def pass_draws(order, n, seed, n1, k=40):
    """What our two-pass rule draws from default_rng(seed): the first ``n1`` draws of the
    mean pass (the Generator itself), then the covariance pass (its first spawned child)."""
    rng = np.random.default_rng(seed)
    child = np.random.default_rng(seed).spawn(1)[0]
    return our_draws(order, n, rng, n1) + our_draws(order, n, child, k)


def assert_close(a, b, rtol=1e-10, what=""):
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * max(1.0, np.abs(b).max()), err_msg=what)


# ------------------------------------------------------------------- points
@pytest.mark.parametrize("order", [1, 3, 5])
@pytest.mark.parametrize("n", [1, 2, 4, 5])
def test_points_and_weights_equal_stone_soup(monkeypatch, order, n):
    if order == 5 and n == 1:
        pytest.skip("Stone Soup's degree-5 midpoints are 0/0 for n = 1 (ours leave them out)")
    pts, w = stochastic_rule_points(n, order, np.random.default_rng(10 + n))
    feed = Feed(order, n, our_draws(order, n, np.random.default_rng(10 + n), 1))
    feed_stone_soup(monkeypatch, feed)
    ss_pts, ss_w = ssf.stochastic_cubature_rule_points(n, order)
    assert feed.draws == 1
    assert_close(pts, ss_pts, 1e-12, "points")
    assert_close(w, ss_w, 1e-12, "weights")
    # and the rule is what it claims: weights sum to one, second moments are the identity
    np.testing.assert_allclose(w.sum(), 1.0, rtol=1e-12)
    if order > 1:
        np.testing.assert_allclose((pts * w) @ pts.T, np.eye(n), atol=1e-12)


def test_degree5_one_dimension_needs_no_midpoints():
    pts, w = stochastic_rule_points(1, 5, np.random.default_rng(0))
    assert pts.shape == (1, 9) and np.isfinite(pts).all()
    for k in range(6):  # exact up to degree 5: E[u^k] for u ~ N(0, 1)
        np.testing.assert_allclose((w * pts[0] ** k).sum(), [1, 0, 1, 0, 3, 0][k], atol=1e-11)


# ------------------------------------------------------------------- update
@pytest.mark.parametrize("name", ["ctm", "ct-rb"])
@pytest.mark.parametrize("order", [3, 5])
@pytest.mark.parametrize("N", [2, 5])
def test_update_equals_stone_soup_draw_for_draw(monkeypatch, name, order, N):
    """Fixed N (Nmin = Nmax = N): z_pred, Pzz (with R and the diagonal Vz) and Pxz agree to 1e-10."""
    model = MODELS[name]()
    x, P = POINTS[name]
    seed = 100 + 10 * order + N
    sif = af.SIF(model, n_iter=N, order=order, passes=2, integration_error="diag")
    z = model.h(x, 1)[:, None]
    u = sif.update_rl(x[:, None], P[:, :, None], z, 0, N, rng=np.random.default_rng(seed))
    feed = Feed(order, model.nx, pass_draws(order, model.nx, seed, N))
    feed_stone_soup(monkeypatch, feed)
    zp, Pzz, Pxz = ss_measurement_prediction(ss_updater(model, order, N, N, 0.0), x, P)
    assert feed.draws == 2 * N and u.n_iter_spent[0] == 2 * N
    assert_close(u.z_pred[:, 0], zp, what="z_pred")
    assert_close(u.Pzz[:, :, 0], Pzz, what="Pzz")
    assert_close(u.Pxz[:, :, 0], Pxz, what="Pxz")
    # the comparison has teeth: the one-pass rule (covariances from the mean's own draws) differs
    one = af.SIF(model, n_iter=N, order=order, integration_error="diag").update_rl(
        x[:, None], P[:, :, None], z, 0, N, rng=np.random.default_rng(seed))
    assert np.abs(one.Pzz[:, :, 0] - Pzz).max() > 1e-8 * np.abs(Pzz).max()
    # and the integration-error term is the variance of the mean of the per-draw means,
    # recomputed here from Stone Soup's own points (it can be far below the 1e-10 above)
    with monkeypatch.context() as mp:
        feed_stone_soup(mp, Feed(order, model.nx, pass_draws(order, model.nx, seed, N)))
        L = np.linalg.cholesky(P)
        S = []
        for _ in range(N):
            pts, w = ssf.stochastic_cubature_rule_points(model.nx, order)
            S.append(model.h((x[:, None] + L @ pts).T, 1).T @ w)
    V = np.var(np.array(S), axis=0, ddof=1) / N
    mo = StochasticIntegrationRule(order=order, passes=2, integration_error="diag").moments(
        lambda X: np.moveaxis(model.h(np.moveaxis(X, 0, -1), 1), -1, 0), x[:, None], P[:, :, None], N,
        rng=np.random.default_rng(seed))
    assert np.all(V > 0)
    np.testing.assert_allclose(np.diag(mo.mean_var[:, :, 0]), V, rtol=1e-6)
    np.testing.assert_allclose(mo.mean_var[:, :, 0], np.diag(np.diag(mo.mean_var[:, :, 0])), rtol=0, atol=0)


@pytest.mark.parametrize("experiment", ["ctm-sif-stateinnov", "ctm-sif-logmaxnis", "ctm-sif-nis"])
def test_the_experiments_run_the_sif_checked_here(monkeypatch, experiment):
    """The Table I experiments' filter is the form above, draw for draw Stone Soup's (its ``-onepass``
    variant, the experiments' form until 2026-11-25, is not)."""
    from adaptfilt.experiment_registry import get_experiment

    N, seed = 3, 321
    x, P = POINTS["ctm"]
    sif = get_experiment(experiment).make_filter()
    z = sif.model.h(x, 1)[:, None]
    u = sif.update_rl(x[:, None], P[:, :, None], z, 0, N, rng=np.random.default_rng(seed))
    feed_stone_soup(monkeypatch, Feed(3, sif.model.nx, pass_draws(3, sif.model.nx, seed, N)))
    zp, Pzz, Pxz = ss_measurement_prediction(ss_updater(sif.model, 3, N, N, 0.0), x, P)
    assert_close(u.z_pred[:, 0], zp, what="z_pred")
    assert_close(u.Pzz[:, :, 0], Pzz, what="Pzz")
    assert_close(u.Pxz[:, :, 0], Pxz, what="Pxz")
    one = get_experiment(experiment + "-onepass").make_filter().update_rl(
        x[:, None], P[:, :, None], z, 0, N, rng=np.random.default_rng(seed))
    assert np.abs(one.Pzz[:, :, 0] - Pzz).max() > 1e-8 * np.abs(Pzz).max()


@pytest.mark.parametrize("name,order,eps", [("ctm", 3, 1e-6), ("ctm", 5, 1e-13), ("ct-rb", 3, 1e-3), ("ct-rb", 5, 1e-11)])
def test_update_tolerance_stopping_equals_stone_soup(monkeypatch, name, order, eps):
    """Nmin = 2, Nmax = 12 and a tolerance: Stone Soup stops each pass where we do. Its pass
    lengths are read off the draws it consumes: only the right mean-pass length n1 makes the
    fed sequence (n1 mean draws, then covariance draws) reproduce our moments."""
    model = MODELS[name]()
    x, P = POINTS[name]
    seed = 7 + order
    sif = af.SIF(model, n_iter=12, order=order, passes=2, integration_error="diag", tol=eps, n_min=2)
    u = sif.update_rl(x[:, None], P[:, :, None], model.h(x, 1)[:, None], 0, 12, rng=np.random.default_rng(seed))
    spent = int(u.n_iter_spent[0])
    assert 4 < spent < 24, f"pick eps so that stopping happens between the bounds (spent {spent})"
    matches = []
    for n1 in range(2, 13):
        feed = Feed(order, model.nx, pass_draws(order, model.nx, seed, n1))
        with monkeypatch.context() as mp:
            feed_stone_soup(mp, feed)
            zp, Pzz, Pxz = ss_measurement_prediction(ss_updater(model, order, 2, 12, eps), x, P)
        same = all(np.allclose(a, b, rtol=1e-10, atol=1e-10 * max(1, np.abs(b).max()))
                   for a, b in ((u.z_pred[:, 0], zp), (u.Pzz[:, :, 0], Pzz), (u.Pxz[:, :, 0], Pxz)))
        if same:
            matches.append((n1, feed.draws))
    assert len(matches) == 1, matches
    assert matches[0][1] == spent  # both passes stopped after the same number of draws


def test_single_iteration_convention_differs_from_stone_soup_by_the_squared_mean(monkeypatch):
    """N = 1: the references' recursion gives V_1 = I_1^2 (the squared estimate); we add nothing."""
    model = ct_range_bearing()
    x, P = POINTS["ct-rb"]
    for order in (3, 5):
        sif = af.SIF(model, n_iter=1, order=order, passes=2, integration_error="diag")
        u = sif.update_rl(x[:, None], P[:, :, None], model.h(x, 1)[:, None], 0, 1, rng=np.random.default_rng(3))
        with monkeypatch.context() as mp:
            feed_stone_soup(mp, Feed(order, model.nx, pass_draws(order, model.nx, 3, 1)))
            zp, Pzz, Pxz = ss_measurement_prediction(ss_updater(model, order, 1, 1, 0.0), x, P)
        assert_close(u.z_pred[:, 0], zp)
        assert_close(u.Pxz[:, :, 0], Pxz)
        assert_close(Pzz - u.Pzz[:, :, 0], np.diag(zp**2), what="Stone Soup's V_1")


# ------------------------------------------------------------------- predict
@pytest.mark.parametrize("order,N,eps", [(3, 3, None), (3, 5, None), (5, 3, None), (5, 5, None), (3, 12, 1e-3), (5, 12, 1e-8)])
def test_predict_equals_stone_soup_draw_for_draw(monkeypatch, order, N, eps):
    """x_pred and P_pred (with Q and the diagonal Vx) of the nonlinear turn-rate model."""
    model = ct_range_bearing()
    x, P = POINTS["ct-rb"]
    seed = 50 + order + N
    sif = af.SIF(model, n_iter=N, order=order, passes=2, integration_error="diag", tol=eps, n_min=2 if eps else 1)
    info = {}
    m_pred, P_pred = sif.predict_rl(x[:, None], P[:, :, None], 0, rng=np.random.default_rng(seed), info=info)
    n_min = 2 if eps else N
    found = []
    for n1 in (range(2, N + 1) if eps else [N]):
        feed = Feed(order, model.nx, pass_draws(order, model.nx, seed, n1))
        with monkeypatch.context() as mp:
            feed_stone_soup(mp, feed)
            xp, Pp = ss_state_prediction(ss_predictor(model, order, n_min, N, 0.0 if eps is None else eps), x, P)
        if np.allclose(m_pred[:, 0], xp, rtol=1e-10, atol=1e-10 * np.abs(xp).max()) and \
                np.allclose(P_pred[:, :, 0], Pp, rtol=1e-10, atol=1e-10 * np.abs(Pp).max()):
            found.append(feed.draws)
    assert found == [int(info["n_iter"][0])], (found, info["n_iter"])
    if eps:
        assert 4 < info["n_iter"][0] < 2 * N  # the tolerance, not a bound, stopped it


# ------------------------------------------------------------------- statistics
def _ss_samples(updater, x, P, K, seed):
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        out = [ss_measurement_prediction(updater, x, P) for _ in range(K)]
    finally:
        np.random.set_state(state)
    return np.array([np.concatenate([zp.ravel(), Pzz.ravel(), Pxz.ravel()]) for zp, Pzz, Pxz in out])


@pytest.mark.parametrize("order", [3, 5])
def test_statistically_equal_to_stone_soup(order):
    """1000 independent Stone Soup updates (its own random numbers) against 1000 of ours
    (one per run): z_pred, Pzz, Pxz agree in mean and spread."""
    model = ctm()
    x = np.array([80.0, 1.0, 30.0, 20.0])
    P = np.diag([400.0, 50.0, 400.0, 50.0])  # wide: the bearing is markedly nonlinear here
    K, N = 1000, 2
    ss = _ss_samples(ss_updater(model, order, N, N, 0.0), x, P, K, seed=order)
    sif = af.SIF(model, n_iter=N, order=order, passes=2, integration_error="diag")
    u = sif.update_rl(np.repeat(x[:, None], K, 1), np.repeat(P[:, :, None], K, 2), np.full((1, K), 0.3), 0, N,
                      rng=np.random.default_rng(order))
    ours = np.concatenate([u.z_pred, u.Pzz.reshape(1, K), u.Pxz.reshape(4, K)]).T
    for j in range(ours.shape[1]):
        a, b = ours[:, j], ss[:, j]
        se = np.sqrt(a.var() / K + b.var() / K)
        assert abs(a.mean() - b.mean()) < 4.5 * se, (j, a.mean(), b.mean(), se)
        iqr = lambda v: np.subtract(*np.percentile(v, [75, 25]))  # noqa: E731
        assert 0.85 < iqr(a) / iqr(b) < 1.18, (j, iqr(a), iqr(b))
        assert stats.ks_2samp(a, b).pvalue > 1e-3, j
    # the samples really vary (a stochastic comparison, not two constants)
    assert ours[:, 0].std() > 1e-5 and ss[:, 1].std() > 1e-6
