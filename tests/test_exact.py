"""Exact references: the Kalman filter against brute-force Gaussian conditioning,
the point-mass filter against the Kalman filter and against normalisation; the bootstrap particle filter
against the Kalman filter."""
import numpy as np
import pytest
from scipy import stats

import adaptfilt as af
from adaptfilt.exact import BootstrapParticleFilter, KalmanFilter

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


def joint_gaussian(F, H, Q, R, m0, P0, T):
    """Mean and covariance of (x_1..x_T, z_1..z_T) built from the noise vector."""
    nx, nz = F.shape[0], H.shape[0]
    # x = A e with e = (x_1, w_1, ..., w_{T-1}); x_t = F^{t-1} x_1 + sum_s F^{t-1-s} w_s
    A = np.zeros((T * nx, T * nx))
    for t in range(T):
        for s in range(t + 1):
            A[t * nx : (t + 1) * nx, s * nx : (s + 1) * nx] = np.linalg.matrix_power(F, t - s)
    e_mean = np.concatenate([m0, np.zeros((T - 1) * nx)])
    e_cov = np.zeros((T * nx, T * nx))
    e_cov[:nx, :nx] = P0
    for s in range(1, T):
        e_cov[s * nx : (s + 1) * nx, s * nx : (s + 1) * nx] = Q
    Hb = np.kron(np.eye(T), H)
    Rb = np.kron(np.eye(T), R)
    mx, Pxx = A @ e_mean, A @ e_cov @ A.T
    return mx, Pxx, Hb @ mx, Hb @ Pxx @ Hb.T + Rb, Pxx @ Hb.T


def test_kalman_filter_equals_batch_conditioning():
    rng = np.random.default_rng(0)
    nx, nz, T = 2, 1, 6
    F = np.array([[1.0, 0.5], [-0.2, 0.9]])
    H = np.array([[1.0, 0.3]])
    Q = np.array([[0.3, 0.1], [0.1, 0.2]])
    R = np.array([[0.5]])
    m0, P0 = np.array([1.0, -1.0]), np.array([[2.0, 0.5], [0.5, 1.0]])
    model = af.models.linear_gaussian(F, H, Q, R, m0, P0)
    traj = model.simulate(3, T, rng=rng)
    run = af.KalmanFilter(model).run(traj.z)
    mx, Pxx, mz, Pzz, Pxz = joint_gaussian(F, H, Q, R, m0, P0, T)
    for r in range(3):
        zr = traj.z[r].ravel()
        for t in range(T):
            o = slice(0, (t + 1) * nz)
            xs = slice(t * nx, (t + 1) * nx)
            G = np.linalg.solve(Pzz[o, o], Pxz[xs, o].T).T
            mean = mx[xs] + G @ (zr[o] - mz[o])
            cov = Pxx[xs, xs] - G @ Pxz[xs, o].T
            np.testing.assert_allclose(run.mean[r, t], mean, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(run.cov[r, t], cov, rtol=1e-10, atol=1e-12)
        # the sum of the per-step log-likelihoods is the marginal log density of z_1..z_T
        ll = stats.multivariate_normal(mz, Pzz).logpdf(zr)
        np.testing.assert_allclose(run.loglik[r].sum(), ll, rtol=1e-10)
        # NIS over the whole sequence: innovations whiten z
        nis_total = (zr - mz) @ np.linalg.solve(Pzz, zr - mz)
        np.testing.assert_allclose(run.nis[r].sum(), nis_total, rtol=1e-10)


def test_kalman_filter_accepts_explicit_F_H_and_2d_z():
    F, H = np.array([[0.9]]), np.array([[2.0]])
    generic = af.StateSpaceModel(f=lambda x, k: 0.9 * x, h=lambda x, k: 2 * x, Q=[[1.0]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
    lin = af.models.linear_gaussian(F, H, [[1.0]], [[1.0]], [0.0], [[1.0]])
    z = lin.simulate(2, 5, rng=0).z
    a = af.KalmanFilter(generic, F=F, H=H).run(z)
    b = af.KalmanFilter(lin).run(z[..., 0])
    np.testing.assert_array_equal(a.mean, b.mean)
    # scalar case by hand at the first step: K = P0 H / (H^2 P0 + R)
    K = 2.0 / 5.0
    np.testing.assert_allclose(a.mean[:, 0, 0], K * z[:, 0, 0])
    np.testing.assert_allclose(a.cov[:, 0, 0, 0], 1.0 - K * 2.0)


SCALAR_LIN = dict(F=[[0.8]], H=[[1.0]], Q=[[0.5]], R=[[0.3]], m0=[1.0], P0=[[2.0]])


def test_point_mass_equals_kalman_on_scalar_linear_model():
    lin = af.models.linear_gaussian(**SCALAR_LIN)
    traj = lin.simulate(10, 20, rng=0)
    kf = af.KalmanFilter(lin).run(traj.z)
    errs = {}
    for dx in (1.0, 0.5, 0.25):
        grid = np.arange(-15.0, 15.0 + dx / 2, dx)
        pmf = af.PointMassFilter(lin, grid=grid).run(traj.z)
        errs[dx] = max(np.abs(pmf.mean - kf.mean).max(), np.abs(pmf.cov - kf.cov).max(), np.abs(pmf.loglik - kf.loglik).max())
    # a Gaussian on a uniform grid converges very fast in the spacing
    assert errs[0.5] < 1e-4 * 0.5
    assert errs[0.25] < 1e-9
    assert errs[1.0] > errs[0.5] > errs[0.25]
    assert errs[1.0] > 1e-4  # a coarse grid is visibly off: the comparison has teeth


def test_point_mass_likelihood_normalised():
    """p(z_1) integrates to one over z, and so does p(z_2 | z_1)."""
    model = af.models.ungm()
    grid = np.linspace(-30, 30, 601)
    zg = np.linspace(-2.0, 30.0, 3201)
    one = af.PointMassFilter(model, grid=grid).run(zg[:, None])
    np.testing.assert_allclose(np.trapezoid(np.exp(one.loglik[:, 0]), zg), 1.0, atol=1e-6)
    # second step: z_1 fixed, z_2 varies
    z = np.stack([np.full_like(zg, 1.2), zg], axis=1)
    two = af.PointMassFilter(model, grid=grid).run(z)
    np.testing.assert_allclose(two.loglik[:, 0], two.loglik[0, 0])
    np.testing.assert_allclose(np.trapezoid(np.exp(two.loglik[:, 1]), zg), 1.0, atol=1e-5)
    # densities integrate to one and their mean is the reported mean
    d = af.PointMassFilter(model, grid=grid).run(z[:5], keep_density_at=(1,))
    p = d.info["density"][1]
    np.testing.assert_allclose(p.sum(1) * 0.1, 1.0, rtol=1e-12)
    np.testing.assert_allclose((p * grid).sum(1) * 0.1, d.mean[:, 1, 0], rtol=1e-12)


def test_point_mass_beats_ukf_on_ungm():
    """The Bayes-optimal (grid) estimate of the bimodal UNGM is far better than a UKF's."""
    model = af.models.ungm()
    traj = model.simulate(40, 60, rng=4)
    pmf = af.PointMassFilter(model, grid=np.linspace(-40, 40, 641)).run(traj.z)
    ukf = af.UKF(model).run(traj.z)
    r_pmf = af.metrics.rmse(traj.x, pmf.mean).mean()
    r_ukf = af.metrics.rmse(traj.x, ukf.mean).mean()
    assert r_pmf < 0.3 * r_ukf, (r_pmf, r_ukf)
    # and it is consistent: its ANEES is near nx = 1
    assert 0.5 < af.metrics.anees(traj.x, pmf.mean, pmf.cov).mean() < 2.0


@pytest.mark.crosscpu
def test_negligible_values_change_no_bit_of_the_point_mass_filter():
    """Setting transition and likelihood values below 1e-150 to zero (the default, for speed: their products
    would be subnormal) leaves means, variances and log-likelihoods bit for bit as with every value kept, on
    UNGM's two-mode densities; a coarse cut (1e-16) does change them, so the check can fail."""
    model = af.models.ungm()
    traj = model.simulate(40, 150, rng=5)
    grid = np.linspace(-45, 45, 901)
    every = af.PointMassFilter(model, grid=grid, negligible=0.0).run(traj.z)
    cut = af.PointMassFilter(model, grid=grid).run(traj.z)
    for k in ("mean", "cov", "loglik"):
        assert np.array_equal(getattr(every, k), getattr(cut, k)), k
    coarse = af.PointMassFilter(model, grid=grid, negligible=1e-16).run(traj.z)
    assert not np.array_equal(every.mean, coarse.mean)


def test_point_mass_argument_errors():
    ungm = af.models.ungm()
    with pytest.raises(ValueError, match="negligible must be"):
        af.PointMassFilter(ungm, negligible=0.1)
    with pytest.raises(ValueError, match="negligible must be"):
        af.PointMassFilter(ungm, negligible=-1e-200)
    with pytest.raises(ValueError, match="scalar models"):
        af.PointMassFilter(af.models.coordinated_turn())
    with pytest.raises(ValueError, match="equally spaced"):
        af.PointMassFilter(ungm, grid=np.array([0.0, 1.0, 3.0, 4.0]))
    with pytest.raises(ValueError, match="increasing 1-D array"):
        af.PointMassFilter(ungm, grid=np.array([1.0, 0.0, -1.0]))
    z = ungm.simulate(3, 10, rng=0).z
    with pytest.raises(ValueError, match="widen the grid"):
        af.PointMassFilter(ungm, grid=np.linspace(-3, 3, 61)).run(z)


# ---------------------------------------------------------------- the bootstrap particle filter
def test_particle_filter_converges_to_the_kalman_filter_on_a_linear_model():
    model = af.models.linear_gaussian(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=[[0.5, 0.5], [0.5, 1.0]],
                                      R=[[4.0]], m0=[0.0, 1.0], P0=np.diag([10.0, 2.0]))
    traj = model.simulate(n_runs=20, n_steps=15, rng=np.random.default_rng(0))
    kf = KalmanFilter(model).run(traj.z)
    pf = BootstrapParticleFilter(model, n_particles=20000, seed=1).run(traj.z)
    sd = np.sqrt(np.diagonal(kf.cov, axis1=-2, axis2=-1))
    err = np.abs(pf.mean - kf.mean) / sd  # Monte-Carlo error of the particle mean, in posterior sds
    assert err.max() < 0.2 and err.mean() < 0.03
    scale = sd[..., :, None] * sd[..., None, :]
    rel = np.abs((pf.cov - kf.cov) / scale)  # covariance error in units of the posterior's (MC sd ~ 0.015)
    assert rel.max() < 0.15 and rel.mean() < 0.03
    dll = np.abs(pf.loglik - kf.loglik)  # the likelihood estimate too (noisier in the tails)
    assert dll.max() < 0.15 and dll.mean() < 0.02
    again = BootstrapParticleFilter(model, n_particles=20000, seed=1).run(traj.z)
    assert np.array_equal(again.mean, pf.mean)


def test_particle_filter_wraps_bearings_and_rejects_bad_input():
    model = af.models.coordinated_turn(n_steps=10)
    traj = model.simulate(n_runs=3, rng=np.random.default_rng(2))
    a = BootstrapParticleFilter(model, n_particles=300, seed=0).run(traj.z)
    b = BootstrapParticleFilter(model, n_particles=300, seed=0).run(traj.z + 2 * np.pi)  # the same bearings
    np.testing.assert_allclose(a.mean, b.mean)
    with pytest.raises(ValueError, match="n_particles"):
        BootstrapParticleFilter(model, n_particles=1)
    with pytest.raises(ValueError, match="ess_threshold"):
        BootstrapParticleFilter(model, ess_threshold=2.0)
    with pytest.raises(ValueError, match=r"z must have shape \(M, T, 1\)"):
        BootstrapParticleFilter(model).run(np.zeros((2, 3, 2)))
