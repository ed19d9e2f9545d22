"""adaptfilt.course.{common, bayes, moments, myopia, adaptation}: the helpers behind the course notebooks, against independent references."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from scipy import integrate, stats  # noqa: E402

import adaptfilt as af  # noqa: E402
from adaptfilt.course import common, bayes, moments, myopia, adaptation  # noqa: E402

GRID = np.linspace(-45, 45, 901)
DX = GRID[1] - GRID[0]


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def gauss(x, m, v):
    return np.exp(-0.5 * (x - m) ** 2 / v) / np.sqrt(2 * np.pi * v)


@pytest.fixture(scope="module")
def ungm_small():
    model = af.models.ungm(n_steps=30)
    return model, model.simulate(n_runs=12, rng=np.random.default_rng(3))


# ---------------------------------------------------------------- chapter 1


def test_grid_bayes_step_is_the_kalman_step_on_a_linear_model():
    lin = af.models.linear_gaussian(F=[[0.9]], H=[[0.5]], Q=[[1.0]], R=[[0.5]], m0=[0.0], P0=[[5.0]])
    grid = np.linspace(-40, 40, 1601)
    m, P, z = 1.0, 2.0, 0.7  # previous filtering N(m, P), measurement at step t = 1
    step = bayes.grid_bayes_step(lin, grid, gauss(grid, m, P), z, t=1)
    m_pred, P_pred = 0.9 * m, 0.81 * P + 1.0
    K = P_pred * 0.5 / (0.25 * P_pred + 0.5)
    m_post, P_post = m_pred + K * (z - 0.5 * m_pred), (1 - 0.5 * K) * P_pred
    dx = grid[1] - grid[0]
    assert np.abs(step.predictive - gauss(grid, m_pred, P_pred)).max() < 1e-10
    assert (grid * step.posterior).sum() * dx == pytest.approx(m_post, abs=1e-10)
    assert ((grid - m_post) ** 2 * step.posterior).sum() * dx == pytest.approx(P_post, abs=1e-10)
    assert np.allclose(step.likelihood, gauss(z, 0.5 * grid, 0.5))


def test_filtering_densities_match_the_point_mass_filter(ungm_small):
    model, traj = ungm_small
    pmf = af.PointMassFilter(model, grid=GRID)
    dens = bayes.filtering_densities(pmf, traj.z[:, :10])
    assert dens.shape == (12, 10, GRID.size)
    ref = pmf.run(traj.z[:, :10])
    assert np.abs(bayes.point_estimates(GRID, dens)["mean"] - ref.mean[..., 0]).max() < 1e-12
    # and one step by hand reproduces step t from step t - 1
    step = bayes.grid_bayes_step(model, GRID, dens[4, 6], traj.z[4, 7, 0], 7)
    assert np.abs(step.posterior - dens[4, 7]).max() < 1e-12


def test_sign_ambiguity_of_a_symmetric_mixture():
    a, v = 8.0, 1.0
    dens = 0.5 * gauss(GRID, -a, v) + 0.5 * gauss(GRID, a, v)
    amb = bayes.sign_ambiguity(GRID, dens[None, None])
    abs_mean = integrate.quad(lambda x: abs(x) * (0.5 * gauss(x, -a, v) + 0.5 * gauss(x, a, v)), -50, 50, points=[0])[0]
    assert amb.p_neg[0, 0] == pytest.approx(0.5, abs=1e-6)
    assert amb.abs_mean[0, 0] == pytest.approx(abs_mean, rel=1e-6)


def test_ambiguous_cases_skip_the_prior_step_and_sort_by_separation():
    p_neg = np.array([[0.5, 0.5, 0.1, 0.4], [0.5, 0.3, 0.5, 0.9]])
    abs_mean = np.array([[9.0, 5.0, 9.0, 7.0], [9.0, 8.0, 3.0, 9.0]])
    amb = bayes.SignAmbiguity(p_neg, abs_mean)
    assert bayes.ambiguous_cases(amb, n=5) == [(1, 1), (0, 3), (0, 1)]
    assert bayes.ambiguous_mask(amb).sum() == 3 and not bayes.ambiguous_mask(amb)[:, 0].any()


def test_point_estimates_against_closed_forms():
    g = stats.gamma(a=2.0, scale=3.0)  # skewed: mean 6, median 5.03, mode 3
    grid = np.linspace(0, 90, 9001)
    est = bayes.point_estimates(grid, g.pdf(grid))
    assert est["mean"] == pytest.approx(6.0, abs=1e-3)
    assert est["median"] == pytest.approx(g.median(), abs=0.011)
    assert est["MAP"] == pytest.approx(3.0, abs=0.011)


def test_expected_loss_is_variance_plus_squared_bias():
    post = 0.3 * gauss(GRID, -6, 2.0) + 0.7 * gauss(GRID, 7, 1.0)
    mean = 0.3 * -6 + 0.7 * 7
    var = 0.3 * (2.0 + 36) + 0.7 * (1.0 + 49) - mean ** 2
    cand = np.linspace(-10, 10, 2001)
    el = bayes.expected_loss(GRID, post, cand)
    assert np.allclose(el.loss, var + (cand - mean) ** 2, atol=1e-8)
    assert el.argmin == pytest.approx(mean, abs=0.01) and el.mean == pytest.approx(mean, abs=1e-9)
    assert el.map == pytest.approx(7.0, abs=0.1)
    assert el.at(el.map) > el.at(el.mean)


def test_score_against_the_metrics_module(ungm_small):
    model, traj = ungm_small
    run = af.UKF(model).run(traj.z)
    counts = af.metrics.bootstrap_counts(12, 300, rng=1)
    s = common.score(traj.x, run, counts)
    assert np.allclose(s.rmse_k, af.metrics.rmse(traj.x, run.mean))
    assert s.rmse == pytest.approx(af.metrics.rmse(traj.x, run.mean).mean())
    assert s.anees == pytest.approx(af.metrics.anees(traj.x, run.mean, run.cov).mean())
    assert s.rmse_ci[0] <= s.rmse <= s.rmse_ci[1]
    assert (s.rmse_band[0] <= s.rmse_band[1]).all()
    se = ((traj.x - run.mean) ** 2).sum(-1)
    assert s.median_run_rmse == pytest.approx(np.median(np.sqrt(se.mean(1))))
    with pytest.raises(ValueError, match="counts must have shape"):
        common.score(traj.x, run, counts[:, :5])
    assert "κ = 2" in common.score_table({"UKF kappa=2": s})


def test_paired_rmse_difference(ungm_small):
    model, traj = ungm_small
    a, b = af.UKF(model, kappa=100).run(traj.z), af.UKF(model).run(traj.z)
    counts = af.metrics.bootstrap_counts(12, 500, rng=2)
    d, lo, hi = common.paired_rmse_difference(traj.x, a, b, counts)
    assert d == pytest.approx(af.metrics.rmse(traj.x, a.mean).mean() - af.metrics.rmse(traj.x, b.mean).mean())
    assert lo <= d <= hi
    assert common.paired_rmse_difference(traj.x, a, a, counts) == (0.0, 0.0, 0.0)


def test_chi2_median():
    assert common.chi2_median(1) == pytest.approx(0.4549364, abs=1e-6)
    x = np.random.default_rng(0).standard_normal(200_000) ** 2
    assert np.median(x) == pytest.approx(common.chi2_median(1), abs=0.01)
    with pytest.raises(ValueError):
        common.chi2_median(0)


# ---------------------------------------------------------------- chapter 2


@pytest.mark.parametrize("m, P", [(5.0, 4.0), (1.0, 12.0), (-3.0, 0.5)])
def test_unscented_pzz_matches_the_closed_form(m, P):
    kappas = np.array([-0.5, 0.0, 1.0, 2.0, 7.5, 100.0])
    assert np.allclose(moments.unscented_pzz(kappas, m, P, R=0.1), (4 * m * m * P + kappas * P * P) / 400 + 0.1)


def test_unscented_cross_covariance_of_a_cubic():
    # Cov[x, x^3/20] = (3 m^2 P + 3 P^2)/20 exactly; the UT has (1 + kappa) P^2 in place of 3 P^2.
    m, P, kappas = 2.0, 3.0, np.array([0.0, 2.0, 5.0])
    mo = moments.unscented_moments(lambda X: X ** 3 / 20, kappas, [m], [[P]])
    assert np.allclose(mo.cross[0, 0], (3 * m * m * P + (1 + kappas) * P * P) / 20)


def test_plot_unscented_draws_the_weights():
    for kappa in (-0.5, 0.0, 2.0, 10.0):
        fig = moments.plot_unscented(kappa, m=5.0, P=4.0)
        ax = fig.axes[0]
        heights = ax.lines[0].get_ydata()
        assert np.allclose(heights, [0.5 / (1 + kappa), kappa / (1 + kappa), 0.5 / (1 + kappa)])
        assert heights.sum() == pytest.approx(1.0)
        assert np.allclose(ax.lines[0].get_xdata(), 5.0 + np.array([-1, 0, 1]) * np.sqrt((1 + kappa) * 4.0))
        pzz = (4 * 25 * 4 + kappa * 16) / 400 + 0.1
        title = ax.get_title()
        assert title.startswith(f"κ = {kappa:g}\n") and f"{pzz:.3g} (exact 1.18)" in title
    with pytest.raises(ValueError, match="1 \\+ kappa > 0"):
        moments.plot_unscented(-1.0)


def test_widget_callbacks_draw_for_several_knob_values(monkeypatch):
    shown = []
    monkeypatch.setattr(plt, "show", lambda *a, **k: shown.append(plt.gcf()))
    for kappa in (-0.9, 0.0, 2.0, 20.0):
        moments.show_unscented(kappa=kappa, m=1.0, P=12.0)
    for n_iter in (1, 8, 64):
        moments.show_sif_draws(n_iter=n_iter)
    assert len(shown) == 7 and all(len(f.axes) == 1 for f in shown)
    errors = [float(f.axes[0].get_title().split()[-1]) for f in shown[4:]]
    assert errors[0] > errors[1] > errors[2]  # the spread narrows with the iterations
    assert errors[0] / errors[2] == pytest.approx(8.0, rel=0.25)  # like n_iter ** -0.5


def test_gauss_hermite_against_closed_forms():
    m, v = moments.gauss_hermite_moments(lambda X: X[0:1] ** 2, [1.0], [[2.0]], order=10)
    assert (m, v) == (pytest.approx(3.0), pytest.approx(4 * 1 * 2 + 2 * 4))
    a, mu, P = np.array([0.5, -2.0]), np.array([1.0, 3.0]), np.array([[2.0, 0.3], [0.3, 1.0]])
    m, v = moments.gauss_hermite_moments(lambda X: np.einsum("i,ipr->pr", a, X)[None], mu, P, order=5)
    assert m == pytest.approx(a @ mu) and v == pytest.approx(a @ P @ a)


def test_rule_errors_unscented_exact_for_quadratics_and_sir_slope():
    g = lambda X: X[0:1] ** 2 + X[1:2]
    m, P = np.array([1.0, 2.0]), np.array([[2.0, 0.5], [0.5, 1.0]])
    ref = moments.gauss_hermite_moments(g, m, P, order=8)
    ut = moments.rule_errors(af.rules.UnscentedRule(), g, m, P, [1.0], ref)
    assert ut.mean[0] < 1e-12  # degree 3: exact mean
    ref_b = moments.gauss_hermite_moments(moments.bearing, (20.0, 5.0), ((25.0, 5.0), (5.0, 16.0)))
    n_iters = np.array([1, 4, 16, 64])
    sir = moments.rule_errors(af.rules.StochasticIntegrationRule(), moments.bearing, (20.0, 5.0),
                             ((25.0, 5.0), (5.0, 16.0)), n_iters, ref_b, n_batch=2000, seed=1)
    slope = np.polyfit(np.log(n_iters), np.log(sir.mean), 1)[0]
    assert -0.6 < slope < -0.4


def test_line_of_sight_errors():
    x = np.array([[[10.0, 0.0, 0.0, 0.0]]])
    mean = np.array([[[8.0, 0.0, 1.0, 0.0]]])
    radial, cross = moments.line_of_sight_errors(x, mean)
    assert radial[0, 0] == pytest.approx(2.0) and cross[0, 0] == pytest.approx(-1.0)
    rng = np.random.default_rng(0)
    x, mean = rng.normal(size=(5, 7, 4)) * 50, rng.normal(size=(5, 7, 4)) * 50
    radial, cross = moments.line_of_sight_errors(x, mean)
    assert np.allclose(radial ** 2 + cross ** 2, ((x - mean)[..., [0, 2]] ** 2).sum(-1))
    with pytest.raises(ValueError, match="origin"):
        moments.line_of_sight_errors(np.zeros((1, 1, 4)), mean[:1, :1])


def test_plots_draw(ungm_small):
    model, traj = ungm_small
    counts = af.metrics.bootstrap_counts(12, 100)
    s = {n: common.score(traj.x, af.UKF(model, kappa=k).run(traj.z), counts) for n, k in [("UKF kappa=2", 2), ("UKF kappa=100", 100)]}
    fig = common.plot_rmse_k(s)
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["UKF κ = 2", "UKF κ = 100"]
    fig = moments.plot_anees_k(s, nx=1, median_of={"UKF kappa=2": s["UKF kappa=2"]})
    assert any("0.455" in t.get_text() for t in fig.axes[0].get_legend().get_texts())
    moments.plot_per_run_rmse(s)
    moments.plot_pzz_vs_kappa(np.linspace(-0.9, 5, 20), [(5.0, 4.0)])
    ref = moments.gauss_hermite_moments(moments.bearing, (20.0, 5.0), ((25.0, 5.0), (5.0, 16.0)))
    e = moments.rule_errors(af.rules.UnscentedRule(), moments.bearing, (20.0, 5.0), ((25.0, 5.0), (5.0, 16.0)), [1.0], ref)
    moments.plot_rule_errors([1, 2], moments.RuleErrors(np.array([1e-2, 7e-3]), np.array([1e-3, 7e-4])), e)
    bayes.plot_ungm_roots(traj, 0)
    dens = bayes.filtering_densities(af.PointMassFilter(model, grid=GRID), traj.z[:2, :4])
    bayes.plot_posteriors(GRID, dens, traj.x, [(0, 1), (1, 2)])
    bayes.plot_bayes_step(GRID, bayes.grid_bayes_step(model, GRID, dens[0, 1], traj.z[0, 2, 0], 2))
    bayes.plot_expected_loss(bayes.expected_loss(GRID, dens[0, 1], np.linspace(-5, 5, 11)))
    r, c = moments.line_of_sight_errors(np.ones((2, 3, 4)), np.zeros((2, 3, 4)))
    fig = moments.plot_line_of_sight_errors(r, c)
    assert "(m)" in fig.axes[0].get_ylabel()


# ---------------------------------------------------------------- chapter 3


def test_decision_loop_is_the_point_mass_filter(ungm_small):
    model, traj = ungm_small
    z = traj.z[:, :12]
    mean = myopia.posterior_mean(GRID)
    base = myopia.decision_loop(model, GRID, mean, z)
    ref = af.PointMassFilter(model, grid=GRID).run(z)
    assert np.abs(base.estimates - ref.mean[..., 0]).max() < 1e-10
    assert np.allclose(base.exp_loss, ref.cov[..., 0, 0], atol=1e-10)  # L-bar at the mean = the variance
    shifted = myopia.decision_loop(model, GRID, lambda s, t: mean(s, t) + 3.0 * (t == 5), z)
    assert np.allclose(shifted.exp_loss[:, 5] - base.exp_loss[:, 5], 9.0)
    assert np.array_equal(np.delete(shifted.exp_loss, 5, axis=1), np.delete(base.exp_loss, 5, axis=1))
    med = myopia.decision_loop(model, GRID, myopia.posterior_median(GRID), z, loss=lambda x, xh: np.abs(x - xh))
    mean_abs = myopia.decision_loop(model, GRID, mean, z, loss=lambda x, xh: np.abs(x - xh))
    assert (med.exp_loss <= mean_abs.exp_loss + 1e-9).all()  # the median minimises the absolute loss
    mp = myopia.decision_loop(model, GRID, myopia.posterior_map(GRID), z)
    assert np.array_equal(mp.estimates, GRID[base.states.argmax(axis=1)].T)


def test_filter_loop_is_ukf_run_with_a_schedule(ungm_small):
    model, traj = ungm_small
    ukf = af.UKF(model)
    kappas = np.where(np.arange(30) == 7, 10.0, 2.0)
    mean, cov = myopia.filter_loop(ukf, traj.z, kappas)
    ref = ukf.run(traj.z, params=np.tile(kappas, (12, 1)))
    assert np.array_equal(mean, ref.mean) and np.array_equal(cov, ref.cov)
    shift = np.where(np.arange(30) == 7, 5.0, 0.0)
    m2, c2 = myopia.filter_loop(ukf, traj.z, kappas, x_shift=shift)
    assert np.array_equal(m2[:, :7], mean[:, :7])
    assert np.allclose(m2[:, 7], mean[:, 7] + 5.0) and np.array_equal(c2[:, 7], cov[:, 7])
    assert (m2[:, 8] != mean[:, 8]).all()


def test_divergence_is_relative():
    mean_b, cov_b = np.zeros((2, 3, 4)), np.tile(np.diag([4.0, 1.0, 5.0, 1.0]), (2, 3, 1, 1))
    mean_a, cov_a = mean_b.copy(), cov_b.copy()
    mean_a[0, 1, [0, 2]] = [3.0, 0.0]
    cov_a[1, 2, 0, 0] = 13.0
    dm, dP = myopia.divergence(mean_a, cov_a, mean_b, cov_b, [0, 2])
    assert dm[0, 1] == pytest.approx(1.0) and dm.sum() == pytest.approx(1.0)  # 3 / sqrt(4 + 5)
    assert dP[1, 2] == pytest.approx(1.0) and dP.sum() == pytest.approx(1.0)  # |18 - 9| / 9


def test_deviation_costs_and_myopic_comparison(ungm_small):
    model, traj = ungm_small
    ukf = af.UKF(model)
    costs = myopia.deviation_costs(ukf, traj.z, [2.0, 50.0], t0=4)
    assert costs.shape == (2, 12, 30)
    assert np.allclose(costs[0], (ukf.run(traj.z).nis - 1) ** 2)
    assert np.array_equal(costs[1, :, :4], costs[0, :, :4])
    assert myopia.myopic_vs_discounted(costs, 4, gamma=0.0).differ == 0.0
    # hand-made: option 0 is cheaper now, option 1 over the horizon
    c = np.zeros((2, 1, 3))
    c[0, 0] = [1.0, 4.0, 0.0]
    c[1, 0] = [2.0, 0.0, 0.0]
    cmp = myopia.myopic_vs_discounted(c, 0, gamma=0.5)
    assert (cmp.myopic[0], cmp.farsighted[0], cmp.differ) == (0, 1, 1.0)
    assert cmp.mean_cost("myopic") == pytest.approx(3.0) and cmp.mean_cost("farsighted") == pytest.approx(2.0)
    with pytest.raises(ValueError, match="gamma"):
        myopia.myopic_vs_discounted(c, 0, gamma=1.5)


def _reader_unscented(f, m, P, kappa, sqrt=np.linalg.cholesky, w0=None, scale=True, w_other=0.5, about_fm=False,
                      rows=False):
    n = m.size
    L = sqrt(P)
    L = L.T if rows else L
    c = np.sqrt(n + kappa) if scale else 1.0
    X = [m] + [m + s * c * L[:, j] for s in (1, -1) for j in range(n)]
    w = np.r_[kappa / (n + kappa) if w0 is None else w0, np.full(2 * n, w_other / (n + kappa))]
    Y = np.array([np.atleast_1d(f(x)) for x in X])
    D = Y - (np.atleast_1d(f(m)) if about_fm else w @ Y)
    return w @ Y, (w[:, None] * D).T @ D


def _reader_unscented_vectorised(f, m, P, kappa):
    """A correct alternative: the points as one array, the covariance by einsum."""
    n = m.size
    S = np.sqrt(n + kappa) * np.linalg.cholesky(P)
    X = np.vstack([m, m + S.T, m - S.T])
    w = np.r_[kappa / (n + kappa), np.full(2 * n, 0.5 / (n + kappa))]
    Y = np.array([np.atleast_1d(f(x)) for x in X])
    mean = w @ Y
    return mean, np.einsum("i,ij,ik->jk", w, Y - mean, Y - mean)


def test_check_unscented_says_correct_only_for_a_correct_transform(capsys):
    from scipy.linalg import sqrtm

    moments.check_unscented(_reader_unscented)
    out = capsys.readouterr().out
    assert out.startswith("correct") and "closed form" in out
    moments.check_unscented(lambda f, m, P, k: _reader_unscented(f, m, P, k, sqrt=lambda A: np.real(sqrtm(A))))
    out = capsys.readouterr().out  # another square root of P: right for n = 1 and a diagonal P, wrong for n = 2
    assert out.startswith("not yet") and "n = 2" in out and "n = 1" not in out and "cholesky" in out
    moments.check_unscented(lambda f, m, P, k: _reader_unscented(f, m, P, k, w0=0.0))  # weights that do not sum to 1
    assert "the mean differs" in capsys.readouterr().out
    moments.check_unscented(_reader_unscented_vectorised)
    assert capsys.readouterr().out.startswith("correct")
    for kw in (dict(about_fm=True),          # the readers' slip: the covariance about f(m), not about the mean
               dict(scale=False),            # points at m +- L[:, j]: sqrt(n + kappa) left out
               dict(w_other=1.0),            # the other weights 1 / (n + kappa), not halved
               dict(rows=True)):             # the rows of the Cholesky factor, not its columns
        moments.check_unscented(lambda f, m, P, k, kw=kw: _reader_unscented(f, m, P, k, **kw))
        assert capsys.readouterr().out.startswith("not yet"), kw
    moments.check_unscented(lambda f, m, P, k: None)
    assert "returned None" in capsys.readouterr().out
    moments.check_unscented(lambda f, m, P, k: 1 / 0)
    assert "raised ZeroDivisionError" in capsys.readouterr().out


def test_check_update_against_the_filters_update(capsys):
    def update(x, P, z, zp, Pzz, Pxz):
        K = Pxz @ np.linalg.inv(Pzz)
        return x + K @ (z - zp), P - K @ Pzz @ K.T

    moments.check_update(update)
    assert capsys.readouterr().out.startswith("correct: your update agrees")
    cases = moments._update_cases()
    assert [u.Pzz.shape[1] for _, u in cases] == [1, 1, 2]  # a two-measurement case catches a scalar division
    for _, u in cases:  # the innovations are not wrapped: z = z_pred + innovation is the measurement
        assert np.abs(u.innovation).max() < 1.0
    moments.check_update(lambda x, P, z, zp, Pzz, Pxz: (x + (Pxz[:, :1] / Pzz[0, 0]) @ (z - zp)[:1], P))
    out = capsys.readouterr().out
    assert out.startswith("not yet") and "P_filt differs" in out and "two measurements (case 0): x_filt differs" in out
    moments.check_update(lambda *a: (1, 2, 3))
    assert "not a pair" in capsys.readouterr().out
    # correct alternatives: P - K Pxz^T (= P - K Pzz K^T), and a solve instead of an inverse
    moments.check_update(lambda x, P, z, zp, Pzz, Pxz: (x + Pxz @ np.linalg.solve(Pzz, z - zp),
                                                        P - Pxz @ np.linalg.inv(Pzz) @ Pxz.T))
    moments.check_update(lambda x, P, z, zp, Pzz, Pxz: (x + np.linalg.solve(Pzz, Pxz.T).T @ (z - zp),
                                                        P - np.linalg.solve(Pzz, Pxz.T).T @ Pxz.T))
    assert capsys.readouterr().out.count("correct: your update agrees") == 2
    wrong = [lambda x, P, z, zp, Pzz, Pxz: (update(x, P, z, zp, Pzz, Pxz)[0],                 # covariance grows
                                            P + Pxz @ np.linalg.inv(Pzz) @ Pxz.T),
             lambda x, P, z, zp, Pzz, Pxz: update(x, P, zp, z, Pzz, Pxz),                # innovation reversed
             lambda x, P, z, zp, Pzz, Pxz: (update(x, P, z, zp, Pzz, Pxz)[0], P)]       # covariance not updated
    for fn in wrong:
        moments.check_update(fn)
        out = capsys.readouterr().out
        assert out.startswith("not yet") and "raised" not in out


# ---------------------------------------------------------------- chapter 4


def test_innovation_spread_is_flat_on_ungm_only():
    from adaptfilt.experiment_registry import get_experiment

    text = adaptation.innovation_spread(get_experiment("ungm-ukf").make_env(), n_runs=2, steps=3)
    rows = [ln.split() for ln in text.splitlines()[1:]]
    assert all(r[3] == r[5] == r[-1] for r in rows)  # the unscented mean of x^2/20 is exact for every kappa
    text = adaptation.innovation_spread(get_experiment("ctm-ukf").make_env(), n_runs=2, steps=3)
    assert any(r.split()[3] != r.split()[5] for r in text.splitlines()[1:])


def test_kappa_sweep_is_the_fixed_update_kappa_filter():
    from adaptfilt.runs import TRAJ_SEED_KEY

    model = af.models.ungm(n_steps=20)
    res = adaptation.kappa_sweep(model, [2.0, 200.0], n_runs=15, seed=4)
    traj = model.simulate(15, 20, rng=np.random.default_rng([TRAJ_SEED_KEY, 4]))
    for v in (2.0, 200.0):
        run = af.UKF(model).run(traj.z, params=v)  # update kappa = v, predict at the default
        assert res[f"fixed-kappa={v:g}"].rmse == pytest.approx(af.metrics.rmse(traj.x, run.mean).mean())
    fig = adaptation.plot_sweep(res, [2.0, 200.0], "UNGM", nx=1)
    assert fig.axes[0].get_xlabel() == "fixed update κ" and fig.axes[0].get_ylabel() == "time-averaged RMSE"
    fig = adaptation.plot_sweep(res, [2.0, 200.0], "CTM", nx=4, unit="m")
    assert fig.axes[0].get_ylabel() == "time-averaged RMSE (m)"
    assert "fixed-kappa=2 " in adaptation.results_lines(res) or "fixed-kappa=2  " in adaptation.results_lines(res)


def test_cost_samples_and_summary():
    from adaptfilt.experiment_registry import UNGM_KAPPA_GRID, get_experiment
    from adaptfilt.mdp import rollout
    from adaptfilt.policies import GreedyPolicy, default_policy

    env = get_experiment("ungm-ukf").make_env(n_steps=10)
    traj = env.model.simulate(8, 10, rng=np.random.default_rng(0))
    pols = [default_policy(2.0, grid=UNGM_KAPPA_GRID), GreedyPolicy(grid=UNGM_KAPPA_GRID)]
    costs = adaptation.cost_samples(env, pols, traj)
    assert np.array_equal(costs["greedy"], rollout(env, pols[1], traj=traj)[1].ravel())
    c = np.concatenate([np.ones(198), [100.0, 100.0]])  # top 1 % = 2 steps carry 200 / 398
    line = adaptation.cost_summary({"x": c})
    assert "median 1 " in line and "max 100" in line and "carry 50% " in line
    adaptation.plot_cost_distribution(costs)


def test_choice_bands_group_the_grid():
    from types import SimpleNamespace as NS

    from adaptfilt.style import param_label

    choices = np.array([[0.5, 0.1, 0.1, 0.2, 0.1], [0.0, 0.0, 0.0, 0.0, 1.0]])
    res = type("Results", (NS,), {"__getitem__": lambda self, n: NS(choices=choices)})(
        grid=np.array([0.0, 1.0, 5.0, 100.0, 1e4]), config={"param_name": "kappa"})
    bands = [(0, 0), (1, 5), (10, 500), (1000, 1e4)]
    sh = adaptation.choice_bands(res, "greedy", bands)
    assert np.allclose(sh, [[0.5, 0.2, 0.2, 0.1], [0, 0, 0, 1]])
    with pytest.raises(ValueError, match="exactly one band"):
        adaptation.choice_bands(res, "greedy", [(0, 0), (2, 1e4)])
    fig = adaptation.plot_choice_bands(res, "greedy", bands)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    k = param_label("kappa")
    assert labels == [f"{k} ≥ 1000", f"10 ≤ {k} ≤ 500", f"1 ≤ {k} ≤ 5", f"{k} = 0"]  # in stack order, top first


def test_separated_modes_is_the_smaller_mass_of_two_modes_beyond_the_gap():
    from scipy import stats

    from adaptfilt.course.particle_count import separated_modes

    grid = np.linspace(-45, 45, 1801)
    one = stats.norm.pdf(grid, 0, 1)                                     # one mode on zero: not two
    two = 0.5 * stats.norm.pdf(grid, -10, 1) + 0.5 * stats.norm.pdf(grid, 10, 1)
    skew = 0.2 * stats.norm.pdf(grid, -10, 1) + 0.8 * stats.norm.pdf(grid, 10, 1)
    m = separated_modes({0: np.stack([one, two]), 1: np.stack([skew, one])}, grid)
    tail = stats.norm.sf(3)                                               # one mode's own mass beyond +-3
    np.testing.assert_allclose(m, [[tail, 0.2], [0.5, tail]], atol=2e-4)


def test_a_split_table_repeats_every_column_that_names_a_row():
    """tables.fit: a claims table split for width keeps claim, experiment, comparison and metric in each
    part (the verdict part is readable without counting rows), and no cell is lost or repeated."""
    from adaptfilt.course.tables import fit

    head = ["claim", "experiment", "comparison", "metric", "a / b", "a - b", "seeds alone", "margin", "verdict"]
    rows = [["C5", f"e{i}", "adaptive lower than default", m, f"{i}.1", f"-{i}.2", "8/8", "0.1", "confirmed"]
            for i in range(3) for m in ("rmse", "cost")]
    wide = "\n".join(["| " + " | ".join(r) + " |" for r in [head]] + ["|" + "---|" * len(head)]
                     + ["| " + " | ".join(r) + " |" for r in rows])
    parts = [p.split("\n") for p in fit(wide).split("\n\n")]
    assert len(parts) == 2
    values = []
    for p in parts:
        cells = [[c.strip() for c in line.strip("|").split("|")] for line in p]
        assert cells[0][:4] == head[:4] and len(cells[0]) <= 7
        assert [r[:4] for r in cells[2:]] == [r[:4] for r in rows]
        values += [c[4:] for c in cells[0:1]][0]
    assert values == head[4:]
    narrow = "| experiment | policy | cost | log(1+L) | RMSE | ANEES | compute | a | b |\n" + "|---" * 9 + "|\n" \
             + "| x | p | 1 | 2 | 3 | 4 | 5 | 6 | 7 |"
    assert fit(narrow).split("\n\n")[1].startswith("| experiment | policy | a | b |")  # cost is a value
