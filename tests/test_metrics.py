"""Metrics against hand computation, and their statistics on a consistent filter."""
import numpy as np
import pytest
from scipy import stats

import adaptfilt as af
from adaptfilt import metrics


def test_rmse_nees_anees_by_hand():
    rng = np.random.default_rng(0)
    M, T, n = 4, 3, 2
    x, mean = rng.standard_normal((M, T, n)), rng.standard_normal((M, T, n))
    G = rng.standard_normal((M, T, n, n))
    cov = G @ G.transpose(0, 1, 3, 2) + np.eye(n)
    rmse, nees = np.zeros(T), np.zeros((M, T))
    for t in range(T):
        acc = 0.0
        for r in range(M):
            e = x[r, t] - mean[r, t]
            acc += e[0] ** 2 + e[1] ** 2
            nees[r, t] = e @ np.linalg.inv(cov[r, t]) @ e
        rmse[t] = np.sqrt(acc / M)
    np.testing.assert_allclose(metrics.rmse(x, mean), rmse, rtol=1e-13)
    np.testing.assert_allclose(metrics.nees(x, mean, cov), nees, rtol=1e-12)
    np.testing.assert_allclose(metrics.anees(x, mean, cov), nees.mean(0), rtol=1e-12)
    np.testing.assert_allclose(metrics.squared_error(x, mean), ((x - mean) ** 2).sum(-1))
    assert metrics.time_average(rmse) == pytest.approx(rmse.mean())
    assert metrics.time_average(rmse, start=1) == pytest.approx(rmse[1:].mean())
    assert metrics.rmse_time_average(metrics.squared_error(x, mean)) == pytest.approx(rmse.mean())
    # scalar state path
    x1, m1, P1 = x[..., :1], mean[..., :1], cov[..., :1, :1]
    np.testing.assert_allclose(metrics.nees(x1, m1, P1), (x1 - m1)[..., 0] ** 2 / P1[..., 0, 0])


def test_metrics_shape_errors():
    with pytest.raises(ValueError, match="must have the same shape"):
        metrics.rmse(np.zeros((2, 3, 1)), np.zeros((2, 4, 1)))
    with pytest.raises(ValueError, match=r"covariances must have shape \(2, 3, 2, 2\)"):
        metrics.nees(np.zeros((2, 3, 2)), np.zeros((2, 3, 2)), np.ones((2, 3, 2)))


def test_kalman_filter_is_consistent():
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    model = af.models.linear_gaussian(F, H, Q=np.diag([0.1, 0.05]), R=[[1.0]], m0=[0.0, 1.0], P0=np.diag([2.0, 1.0]))
    M, T = 300, 40
    traj = model.simulate(M, T, rng=1)
    run = af.KalmanFilter(model).run(traj.z)
    an = metrics.anees(traj.x, run.mean, run.cov)
    lo, hi = metrics.chi2_bounds(model.nx, M)
    inside = np.mean((an > lo) & (an < hi))
    assert inside > 0.85, inside  # ideally 0.95
    assert abs(an.mean() - 2.0) < 0.15
    # KF innovations are white: the average NIS over runs and steps is chi2(nz * M * T) / (M T)
    lo, hi = metrics.chi2_bounds(model.nz, M * T, level=0.999)
    assert lo < run.nis.mean() < hi
    # a filter that is told the wrong R is flagged inconsistent by the same bounds
    wrong = af.KalmanFilter(af.models.linear_gaussian(F, H, np.diag([0.1, 0.05]), [[0.3]], [0.0, 1.0], np.diag([2.0, 1.0])))
    assert wrong.run(traj.z).nis.mean() > hi


def test_chi2_bounds_cover_by_simulation():
    rng = np.random.default_rng(2)
    for dof, n in ((1, 10), (4, 50)):
        lo, hi = metrics.chi2_bounds(dof, n, level=0.9)
        avg = rng.chisquare(dof, size=(20000, n)).mean(1)
        cover = np.mean((avg > lo) & (avg < hi))
        assert abs(cover - 0.9) < 0.01, cover
        assert lo < dof < hi


def test_bootstrap_and_mean_ci_cover():
    rng = np.random.default_rng(3)
    reps, n = 300, 80
    hits_boot = hits_se = 0
    counts = metrics.bootstrap_counts(n, n_boot=500, rng=0)
    assert counts.shape == (500, n) and np.all(counts.sum(1) == n)
    for _ in range(reps):
        v = rng.exponential(2.0, n)  # true mean 2
        lo, hi = metrics.percentile_ci(metrics.bootstrap_mean(v, counts), level=0.9)
        hits_boot += lo < 2.0 < hi
        m, lo, hi = metrics.mean_ci(v, level=0.9)
        assert m == pytest.approx(v.mean())
        hits_se += lo < 2.0 < hi
    # 90% intervals: coverage within binomial noise (sd ~ 0.017), skewed data undercovers slightly
    assert 0.82 < hits_boot / reps < 0.96
    assert 0.82 < hits_se / reps < 0.96


def test_bootstrap_rmse_by_hand_and_paired():
    rng = np.random.default_rng(4)
    M, T = 30, 12
    se_a = rng.exponential(1.0, (M, T))
    se_b = se_a * rng.uniform(0.9, 1.1, (M, T))
    # counts of one each is the plain time-averaged RMSE
    ones = np.ones((1, M))
    assert metrics.bootstrap_rmse(se_a, ones)[0] == pytest.approx(metrics.rmse_time_average(se_a))
    # a resample by hand
    counts = metrics.bootstrap_counts(M, n_boot=200, rng=5)
    b = 7
    idx = np.repeat(np.arange(M), counts[b].astype(int))
    assert metrics.bootstrap_rmse(se_a, counts)[b] == pytest.approx(np.sqrt(se_a[idx].mean(0)).mean())
    assert metrics.bootstrap_mean(se_a[:, 0], counts)[b] == pytest.approx(se_a[idx, 0].mean())
    # paired: identical inputs give an exactly zero difference in every replicate
    d = metrics.bootstrap_rmse(se_a, counts) - metrics.bootstrap_rmse(se_a.copy(), counts)
    assert np.all(d == 0)
    lo, hi = metrics.percentile_ci(d)
    assert lo == hi == 0
    # paired differences of correlated inputs are much narrower than unpaired ones
    other = metrics.bootstrap_counts(M, n_boot=200, rng=6)
    paired = metrics.bootstrap_rmse(se_a, counts) - metrics.bootstrap_rmse(se_b, counts)
    unpaired = metrics.bootstrap_rmse(se_a, counts) - metrics.bootstrap_rmse(se_b, other)
    assert paired.std() < 0.3 * unpaired.std()
    # same seed, same counts
    np.testing.assert_array_equal(counts, metrics.bootstrap_counts(M, n_boot=200, rng=5))


def test_percentile_ci_matches_quantiles():
    r = np.arange(1001.0)
    assert metrics.percentile_ci(r, 0.9) == pytest.approx((50.0, 950.0))
    m, lo, hi = metrics.mean_ci(np.array([1.0, 2.0, 3.0, 4.0]), level=0.95)
    se = np.std([1, 2, 3, 4], ddof=1) / 2
    assert (lo, hi) == pytest.approx((2.5 - stats.norm.ppf(0.975) * se, 2.5 + stats.norm.ppf(0.975) * se))


def test_divergent_and_its_step_are_one_definition():
    """A run ends divergent exactly when its running NEES average is above the line at the last step;
    its divergence step is the first step where that average crossed it."""
    from adaptfilt.metrics import DIVERGED_NEES, divergence_step, divergent
    rng = np.random.default_rng(3)
    nees_runs = rng.chisquare(2, size=(400, 50)) * np.where(rng.random((400, 1)) < 0.1, 10 ** rng.uniform(3, 6, (400, 1)), 1)
    nees_runs[5, 7] = np.nan  # a lost filter counts as diverged from there on
    bad, step = divergent(nees_runs, nx=2), divergence_step(nees_runs, nx=2)
    assert 0 < bad.sum() < 400 and bad[5]
    running = np.cumsum(nees_runs, axis=1) / np.arange(1, 51)
    np.testing.assert_array_equal(bad, ~(running[:, -1] <= DIVERGED_NEES * 2))
    assert np.all(step[bad] >= 0) and step[5] == 7
    for i in np.flatnonzero(step >= 0)[:40]:
        k = step[i]
        assert not (running[i, k] <= DIVERGED_NEES * 2) and np.all(running[i, :k] <= DIVERGED_NEES * 2)
    with pytest.raises(ValueError, match="must be \\(M, T\\)"):
        divergent(np.ones(5), nx=2)


def test_nees_marks_every_indefinite_covariance_whatever_column_it_fails_at():
    """The batched Cholesky names the members that fail at its first failing column; one that fails at a
    later column (here a singular P whose third pivot is zero) must be marked too, not raised."""
    P = np.tile(np.eye(3), (3, 1, 1))
    P[0, 0, 0] = -1.0                                        # fails at the first column
    P[1] = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 1.0]])   # fails at the third
    x = np.ones((3, 1, 3))
    for mode, mark in (("inf", np.inf), ("nan", np.nan)):
        out = metrics.nees(x, np.zeros_like(x), P[:, None], on_indefinite=mode)
        np.testing.assert_array_equal(out[:2, 0], [mark, mark])
        assert out[2, 0] == pytest.approx(3.0)


def test_a_run_with_an_infinite_error_makes_infinite_only_the_resamples_that_draw_it():
    """0 * inf is NaN in a plain matrix product: a diverged run (infinite error) must make the replicates that
    draw it infinite and leave the others as they are (and finite values give the plain product's bits)."""
    from adaptfilt.metrics import bootstrap_counts, bootstrap_mean, bootstrap_rmse, resampled_sums

    rng = np.random.default_rng(0)
    counts = bootstrap_counts(50, 200, rng=1)
    v = rng.random(50)
    assert np.array_equal(resampled_sums(counts, v), counts @ v)
    w = v.copy()
    w[7] = np.inf
    drawn = counts[:, 7] > 0
    assert 0 < drawn.sum() < len(drawn)
    b = bootstrap_mean(w, counts)
    assert np.isposinf(b[drawn]).all() and np.array_equal(b[~drawn], (counts @ np.where(np.isfinite(w), w, 0))[~drawn] / 50)
    se = rng.random((50, 4))
    se[7, 2] = np.inf
    r = bootstrap_rmse(se, counts)
    assert np.isposinf(r[drawn]).all() and np.isfinite(r[~drawn]).all()
    w[9] = -np.inf
    both = drawn & (counts[:, 9] > 0)
    assert np.isnan(resampled_sums(counts, w)[both]).all()
