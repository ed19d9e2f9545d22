"""Gaussian-assumed filters (UKF, SIF, CKF) against the Kalman filter, filterpy,
a rotated frame, and their own per-run / public-step equivalents; errors."""
import dataclasses

import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints, UnscentedKalmanFilter

import adaptfilt as af
from adaptfilt.linalg import wrap_angle

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


# ------------------------------------------------------------------ helpers
def random_linear(seed, nx, nz):
    """A random stable linear-Gaussian problem: (F, H, Q, R, m0, P0)."""
    rng = np.random.default_rng(seed)

    def spd(n, s):
        G = rng.standard_normal((n, n))
        return s * (G @ G.T / n + 0.3 * np.eye(n))

    F = rng.standard_normal((nx, nx))
    F *= rng.uniform(0.5, 1.05) / max(abs(np.linalg.eigvals(F)))
    H = rng.standard_normal((nz, nx))
    return F, H, spd(nx, rng.uniform(0.05, 2)), spd(nz, rng.uniform(0.05, 2)), rng.standard_normal(nx) * 3, spd(nx, 4)


def generic_model(F, H, Q, R, m0, P0):
    """The linear model through plain callables (no F/H): the rules are exercised."""
    return af.StateSpaceModel(f=lambda x, k: x @ F.T, h=lambda x, k: x @ H.T, Q=Q, R=R, m0=m0, P0=P0, name="lin-generic")


def assert_runs_equal(a, b, rtol=1e-9, what=""):
    """FilterRun equality to rtol, relative to the scale of each quantity."""
    for name in ("mean", "cov", "nis", "loglik"):
        x, y = getattr(a, name), getattr(b, name)
        scale = max(1.0, np.abs(y).max())
        np.testing.assert_allclose(x, y, rtol=rtol, atol=rtol * scale, err_msg=f"{what} {name}")


# ------------------------------------------------------ equality with the KF
LINEAR_CASES = [(1, 1, 1), (2, 1, 2), (3, 2, 2), (4, 3, 3), (6, 4, 1), (5, 5, 2)]  # (seed, nx, nz)


@pytest.mark.parametrize("seed,nx,nz", LINEAR_CASES)
def test_ukf_and_sif_equal_kalman_filter_on_linear_models(seed, nx, nz):
    F, H, Q, R, m0, P0 = random_linear(seed, nx, nz)
    lin = af.models.linear_gaussian(F, H, Q, R, m0, P0)
    traj = lin.simulate(n_runs=8, n_steps=25, rng=seed)
    kf = af.KalmanFilter(generic_model(F, H, Q, R, m0, P0), F=F, H=H).run(traj.z)
    gen = generic_model(F, H, Q, R, m0, P0)
    assert gen.F is None and gen.H is None
    for kappa in (-0.5 * nx, -0.2 * nx, 0.0, 3.0 - nx, 1.0, 10.0, 1e3):
        if nx + kappa <= 0:
            continue
        assert_runs_equal(af.UKF(gen, kappa=kappa).run(traj.z), kf, what=f"UKF kappa={kappa}")
    for n_iter in (1, 2, 10):
        assert_runs_equal(af.SIF(gen, n_iter=n_iter, seed=seed).run(traj.z), kf, what=f"SIF n_iter={n_iter}")
    assert_runs_equal(af.CKF(gen).run(traj.z), kf, what="CKF")
    # the exact linear shortcut (model declares F, H)
    assert_runs_equal(af.UKF(lin, kappa=0.5).run(traj.z), kf, what="UKF shortcut")
    assert_runs_equal(af.SIF(lin, n_iter=3).run(traj.z), kf, what="SIF shortcut")
    # only F declared (exact predict, unscented update) and only H declared
    assert_runs_equal(af.UKF(dataclasses.replace(gen, F=F), kappa=2.0).run(traj.z), kf, what="F only")
    assert_runs_equal(af.UKF(dataclasses.replace(gen, H=H), kappa=2.0).run(traj.z), kf, what="H only")


def test_kf_comparison_is_not_vacuous():
    """A wrong model (Q scaled) is detected by the same comparison."""
    F, H, Q, R, m0, P0 = random_linear(3, 3, 2)
    traj = af.models.linear_gaussian(F, H, Q, R, m0, P0).simulate(4, 10, rng=0)
    kf = af.KalmanFilter(generic_model(F, H, Q, R, m0, P0), F=F, H=H).run(traj.z)
    wrong = af.UKF(generic_model(F, H, Q * 1.001, R, m0, P0)).run(traj.z)
    with pytest.raises(AssertionError):
        assert_runs_equal(wrong, kf)


# --------------------------------------------------------- filterpy reference
def filterpy_ukf(model, z, kappa, bearing=False):
    """filterpy's UKF with Julier sigma points, bridged to Algorithm 1's conventions."""
    n, nz = model.nx, model.nz
    points = JulierSigmaPoints(n, kappa=kappa)
    kw = {}
    if bearing:

        def z_mean(sigmas, Wm):  # circular mean about the centre point's bearing, as in rules.py
            z0 = sigmas[0]
            return z0 + Wm @ wrap_angle(sigmas - z0)

        kw = dict(z_mean_fn=z_mean, residual_z=lambda a, b: wrap_angle(a - b))
    ukf = UnscentedKalmanFilter(
        n, nz, 1.0, hx=lambda x, k: model.h(x, k), fx=lambda x, dt, k: model.f(x, k), points=points, **kw
    )
    M, T = z.shape[:2]
    X, P, ll, nis = np.empty((M, T, n)), np.empty((M, T, n, n)), np.empty((M, T)), np.empty((M, T))
    for r in range(M):
        ukf.x, ukf.P, ukf.Q, ukf.R = model.m0.copy(), model.P0.copy(), model.Q.copy(), model.R.copy()
        for t in range(T):
            if t:
                ukf.predict(k=t)  # array t-1 -> t uses f(x, k=t)
            # Algorithm 1 draws the update's sigma points from (x_pred, P_pred);
            # the first step is an update of the prior with no predict before it
            ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
            ukf.update(z[r, t], k=t + 1)
            X[r, t], P[r, t], ll[r, t] = ukf.x, ukf.P, ukf.log_likelihood
            nis[r, t] = ukf.y @ np.linalg.solve(ukf.S, ukf.y)
    return X, P, ll, nis


@pytest.mark.parametrize(
    "name,kappa,T",
    [("ungm", 2.0, 100), ("ungm", 0.5, 100), ("ungm", 7.0, 100), ("ctm", 0.0, 150), ("ctm", -1.0, 150), ("ctm", 1.0, 150)],
)
def test_ukf_matches_filterpy(name, kappa, T):
    model = af.models.ungm() if name == "ungm" else af.models.coordinated_turn()
    traj = model.simulate(2, T, rng=11)
    X, P, ll, nis = filterpy_ukf(model, traj.z, kappa, bearing=name == "ctm")
    models = [model] if model.F is None else [model, dataclasses.replace(model, F=None)]  # CTM: also generic predict
    for mdl in models:
        run = af.UKF(mdl, kappa=kappa).run(traj.z)
        np.testing.assert_allclose(run.mean, X, rtol=1e-8, atol=1e-8 * np.abs(X).max())
        for r in range(run.n_runs):
            for t in range(T):
                np.testing.assert_allclose(run.cov[r, t], P[r, t], rtol=1e-8, atol=1e-8 * np.abs(P[r, t]).max())
        np.testing.assert_allclose(run.loglik, ll, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(run.nis, nis, rtol=1e-7, atol=1e-9)
    # another kappa gives a different filterpy answer (the comparison has teeth)
    X2 = filterpy_ukf(model, traj.z[:1, :20], kappa + 1.0, bearing=name == "ctm")[0]
    assert np.abs(X2 - X[:1, :20]).max() > 1e-6


# ---------------------------------------------------------- per-run parameters
def test_per_run_kappa_equals_separate_runs():
    model = af.models.ungm()
    traj = model.simulate(4, 40, rng=2)
    kappas = np.array([0.0, 0.5, 2.0, 10.0])  # UNGM loses definiteness quickly at kappa < 0
    ukf = af.UKF(model)
    batched = ukf.run(traj.z, params=kappas)
    np.testing.assert_array_equal(batched.params, np.repeat(kappas[:, None], 40, 1))
    for r, k in enumerate(kappas):
        one = af.UKF(model).run(traj.z[r : r + 1], params=k)
        for name in ("mean", "cov", "nis", "loglik"):
            np.testing.assert_allclose(getattr(batched, name)[r], getattr(one, name)[0], rtol=1e-12, atol=1e-12)
    # the parameter matters on UNGM: the runs with other kappa differ from the default
    default = ukf.run(traj.z)
    assert np.abs(default.mean[0] - batched.mean[0]).max() > 1e-3


def test_kappa_schedule_equals_manual_steps():
    """An (M, T) schedule equals stepping each run alone with the public predict/update."""
    model = af.models.ungm()
    M, T = 3, 30
    traj = model.simulate(M, T, rng=3)
    sched = np.random.default_rng(0).choice([0.0, 1.0, 2.0, 5.0], size=(M, T))
    ukf = af.UKF(model)
    run = ukf.run(traj.z, params=sched, keep_pred=True)
    np.testing.assert_array_equal(run.params, sched)
    for r in range(M):
        x, P = model.m0[None], model.P0[None]
        for t in range(T):
            if t:
                pr = ukf.predict(x, P, t - 1)
                x, P = pr.x_pred, pr.P_pred
            np.testing.assert_allclose(run.x_pred[r, t], x[0], rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(run.P_pred[r, t], P[0], rtol=1e-12)
            u = ukf.update(x, P, traj.z[r : r + 1, t], t, param=sched[r, t])
            x, P = u.x_filt, u.P_filt
            np.testing.assert_allclose(run.mean[r, t], x[0], rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(run.cov[r, t], P[0], rtol=1e-12)
            np.testing.assert_allclose(run.nis[r, t], u.nis[0], rtol=1e-12)
            np.testing.assert_allclose(run.loglik[r, t], u.loglik[0], rtol=1e-12)


def test_update_returns_consistent_quantities():
    model = af.models.coordinated_turn()
    ukf = af.UKF(model)
    rng = np.random.default_rng(4)
    M = 5
    x = model.m0 + rng.standard_normal((M, 4)) * 10
    P = np.repeat(model.P0[None], M, 0)
    z = rng.uniform(-np.pi, np.pi, (M, 1))
    u = ukf.update(x, P, z, 0)
    np.testing.assert_allclose(u.K, u.Pxz @ np.linalg.inv(u.Pzz), rtol=1e-10)
    np.testing.assert_allclose(u.x_filt, x + (u.K @ u.innovation[..., None])[..., 0], rtol=1e-12)
    np.testing.assert_allclose(u.P_filt, P - u.K @ u.Pzz @ u.K.transpose(0, 2, 1), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(u.nis, u.innovation[:, 0] ** 2 / u.Pzz[:, 0, 0], rtol=1e-12)
    ll = -0.5 * (u.nis + np.log(2 * np.pi * u.Pzz[:, 0, 0]))
    np.testing.assert_allclose(u.loglik, ll, rtol=1e-12)
    assert np.all(np.abs(u.innovation) <= np.pi)


def test_sif_per_run_n_iter_shares_random_numbers():
    """Per-run n_iter: each run equals the scalar-n_iter filter with the same seed (common random numbers)."""
    model = af.models.coordinated_turn()
    traj = model.simulate(6, 15, rng=5)
    its = np.array([1, 3, 10, 1, 3, 10])
    sif = af.SIF(model, n_iter=10, seed=7)
    per_run = sif.run(traj.z, params=its)
    for N in (1, 3, 10):
        sel = its == N
        scalar = af.SIF(model, n_iter=10, seed=7).run(traj.z, params=N)
        np.testing.assert_allclose(per_run.mean[sel], scalar.mean[sel], rtol=1e-11)
        np.testing.assert_allclose(per_run.cov[sel], scalar.cov[sel], rtol=1e-10, atol=1e-10)
    # n_iter changes the answer
    assert np.abs(per_run.mean[0] - per_run.mean[1]).max() > 1e-6


# ----------------------------------------------------------------- seeds
def test_sif_seeds():
    model = af.models.coordinated_turn()
    traj = model.simulate(3, 20, rng=6)
    a = af.SIF(model, n_iter=2, seed=1).run(traj.z)
    b = af.SIF(model, n_iter=2, seed=1).run(traj.z)
    c = af.SIF(model, n_iter=2, seed=2).run(traj.z)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.cov, b.cov)
    assert np.all(a.mean[:, 1:] != c.mean[:, 1:])
    # a rerun of the same filter object is identical too (no hidden state)
    sif = af.SIF(model, n_iter=2, seed=1)
    sif.run(traj.z[:1])
    np.testing.assert_array_equal(sif.run(traj.z).mean, a.mean)


# -------------------------------------------------------------- bearing wrap
def negative_axis_ctm(sign):
    """CTM with the target near the negative (sign=+1) or, rotated 180 degrees, the positive x-axis."""
    base = af.models.coordinated_turn(R=0.01)
    return dataclasses.replace(
        base, m0=sign * np.array([-80.0, 0.0, 0.0, 0.5]), P0=np.diag([4.0, 0.1, 4.0, 0.1]), F=None, name="ctm-rot"
    )


@pytest.mark.parametrize("rule", ["ukf", "sif"])
def test_bearing_wrapping_across_pi_matches_rotated_frame(rule):
    near_pi, near_0 = negative_axis_ctm(+1), negative_axis_ctm(-1)
    traj = near_pi.simulate(6, 12, rng=8)
    z = wrap_angle(traj.z)
    assert (z > 3.0).any() and (z < -3.0).any(), "bearings should straddle +-pi"
    z_rot = wrap_angle(z - np.pi)  # bearing in the rotated frame: nothing wraps there
    assert np.abs(z_rot).max() < 1.0
    make = (lambda m: af.UKF(m, kappa=1.0)) if rule == "ukf" else (lambda m: af.SIF(m, n_iter=3, seed=0))
    a = make(near_pi).run(z, keep_pred=True)
    b = make(near_0).run(z_rot, keep_pred=True)
    # estimates rotate back: x -> -x, P unchanged
    np.testing.assert_allclose(a.mean, -b.mean, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(a.cov, b.cov, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(a.nis, b.nis, rtol=1e-7, atol=1e-9)
    assert np.all(a.nis < 30)
    # one update checked by hand: z_pred near pi, innovation small
    f = make(near_pi)
    u = f.update(a.x_pred[:, 3], a.P_pred[:, 3], z[:, 3], 3)
    u_rot = make(near_0).update(b.x_pred[:, 3], b.P_pred[:, 3], z_rot[:, 3], 3)
    np.testing.assert_allclose(wrap_angle(u.z_pred - np.pi), u_rot.z_pred, atol=1e-9)
    np.testing.assert_allclose(u.innovation, u_rot.innovation, atol=1e-9)
    assert np.all(np.abs(u.innovation) < 1.0)


def test_bearing_without_wrapping_goes_wrong():
    """The same problem without the residual: the rotated-frame comparison fails (the test has teeth)."""
    near_pi, near_0 = negative_axis_ctm(+1), negative_axis_ctm(-1)
    traj = near_pi.simulate(6, 12, rng=8)
    z = wrap_angle(traj.z)
    raw = dataclasses.replace(near_pi, residual=None)
    a = af.UKF(raw, kappa=1.0).run(z)
    b = af.UKF(near_0, kappa=1.0).run(wrap_angle(z - np.pi))
    assert np.abs(a.mean + b.mean).max() > 1.0


# --------------------------------------------------------------- bad inputs
def test_bad_kappa_and_n_iter():
    ungm, ctm = af.models.ungm(), af.models.coordinated_turn()
    for bad in (-1.0, -2.0):
        with pytest.raises(ValueError, match=r"kappa must satisfy n \+ kappa > 0 \(n = 1\)"):
            af.UKF(ungm, kappa=bad)
    with pytest.raises(ValueError, match=r"kappa must satisfy n \+ kappa > 0 \(n = 4\)"):
        af.UKF(ctm, kappa=-4.0)
    traj = ungm.simulate(3, 5, rng=0)
    with pytest.raises(ValueError, match=r"kappa must satisfy n \+ kappa > 0"):
        af.UKF(ungm).run(traj.z, params=np.array([0.0, -1.0, 2.0]))
    sched = np.zeros((3, 5))
    sched[2, 4] = -1.5
    with pytest.raises(ValueError, match=r"kappa must satisfy n \+ kappa > 0"):
        af.UKF(ungm).run(traj.z, params=sched)
    for bad in (0, 2.5, -3):
        with pytest.raises(ValueError, match="n_iter must be a positive integer"):
            af.SIF(ctm, n_iter=bad)
    with pytest.raises(ValueError, match="n_iter must be a positive integer"):
        af.SIF(ungm).run(traj.z, params=np.array([1, 0, 2]))
    with pytest.raises(ValueError, match="n_iter must be a positive integer"):
        af.SIF(ungm).run(traj.z, params=2.5)


def test_bad_z_and_params():
    model = af.models.coordinated_turn()
    ukf = af.UKF(model)
    z = model.simulate(3, 5, rng=0).z
    with pytest.raises(ValueError, match=r"z must have shape \(M, T, nz=1\)"):
        ukf.run(z[..., 0].reshape(3, 5, 1, 1))
    with pytest.raises(ValueError, match=r"z must have shape \(M, T, nz=1\)"):
        ukf.run(np.zeros((3, 5, 2)))
    with pytest.raises(ValueError, match=r"z must have shape"):
        ukf.run(np.zeros(5))
    bad = z.copy()
    bad[1, 3, 0] = np.nan
    with pytest.raises(ValueError, match=r"z has non-finite values \(first at run 1, step 3\)"):
        ukf.run(bad)
    bad[1, 3, 0] = np.inf
    with pytest.raises(ValueError, match=r"non-finite"):
        ukf.run(bad)
    with pytest.raises(ValueError, match=r"params must be a scalar, \(M,\) = \(3,\) or \(M, T\) = \(3, 5\)"):
        ukf.run(z, params=np.zeros(4))
    with pytest.raises(ValueError, match=r"params must be"):
        ukf.run(z, params=np.zeros((5, 3)))
    # (M, T) for nz = 1 is accepted and equals (M, T, 1)
    np.testing.assert_array_equal(ukf.run(z[..., 0]).mean, ukf.run(z).mean)
    with pytest.raises(ValueError, match="on_indefinite must be 'raise' or 'clip'"):
        af.UKF(model, on_indefinite="ignore")
    with pytest.raises(TypeError, match="model must be a StateSpaceModel"):
        af.UKF("ungm")


def test_kalman_filter_refuses_nonlinear_model():
    with pytest.raises(ValueError, match=r"Kalman filter needs a linear model: model 'ungm' has no F/H"):
        af.KalmanFilter(af.models.ungm())
    with pytest.raises(ValueError, match="linear model"):
        af.KalmanFilter(af.models.coordinated_turn())  # F but no H


# --------------------------------------------------------------- FilterError
def squared_measurement_model():
    """x_{k+1} = 0*x + w (P_pred = Q = 1, x_pred = 0), z = x^2 + v with tiny R.

    For the UT at x_pred = 0: Pzz = kappa * P_pred^2 + R, negative for kappa < 0.
    """
    return af.StateSpaceModel(
        f=lambda x, k: 0.0 * x, h=lambda x, k: x * x, Q=[[1.0]], R=[[1e-3]], m0=[0.0], P0=[[1.0]], name="sq"
    )


def test_filter_error_names_quantity_step_and_runs():
    model = squared_measurement_model()
    M, T = 4, 6
    z = model.simulate(M, T, rng=0).z
    sched = np.full((M, T), 2.0)
    sched[[1, 2], 3] = -0.5
    with pytest.raises(af.FilterError, match=r"Pzz is not positive definite at step t=3 \(k=4\) in run\(s\) 1, 2$") as e:
        af.UKF(model).run(z, params=sched)
    assert e.value.step == 3 and list(e.value.runs) == [1, 2]
    # the documented repair: completes, finite, counts the repaired runs, leaves the others alone
    clip = af.UKF(model, on_indefinite="clip").run(z, params=sched)
    assert clip.n_repairs == 2
    assert np.isfinite(clip.mean).all() and np.isfinite(clip.cov).all() and np.isfinite(clip.nis).all()
    assert np.all(np.linalg.eigvalsh(clip.cov) > 0)
    ok = af.UKF(model).run(z[[0, 3]], params=2.0)
    np.testing.assert_allclose(clip.mean[[0, 3]], ok.mean, rtol=1e-13)


def test_filter_error_on_ungm_with_kappa_near_minus_n():
    model = af.models.ungm()
    z = model.simulate(20, 50, rng=1).z
    with pytest.raises(af.FilterError, match=r"not positive definite at step t=\d+ \(k=\d+\) in run\(s\) \d+") as e:
        af.UKF(model, kappa=-0.9).run(z)
    assert e.value.runs.size > 0
    clip = af.UKF(model, kappa=-0.9, on_indefinite="clip").run(z)
    assert clip.n_repairs > 0
    for name in ("mean", "cov", "nis", "loglik"):
        assert np.isfinite(getattr(clip, name)).all(), name
    # the default kappa never fails and never produces NaN
    run = af.UKF(model).run(z)
    assert run.n_repairs == 0 and np.isfinite(run.mean).all() and np.isfinite(run.loglik).all()


# ----------------------------------------------------------- misc behaviour
def test_defaults_and_repr():
    ungm, ctm = af.models.ungm(), af.models.coordinated_turn()
    assert af.UKF(ungm).kappa == 2.0 and af.UKF(ctm).kappa == 0.0
    assert af.SIF(ctm).n_iter == 10
    assert "kappa=2" in repr(af.UKF(ungm))
    run = af.UKF(ungm).run(ungm.simulate(2, 7, rng=0).z)
    assert (run.n_runs, run.n_steps) == (2, 7)
    assert run.mean.shape == (2, 7, 1) and run.cov.shape == (2, 7, 1, 1) and run.nis.shape == (2, 7)
    assert run.x_pred is None


# ------------------------------------------------- SIF variants, modified UKF
SIF_VARIANTS = [
    dict(order=5),
    dict(order=3, passes=2),
    dict(order=5, passes=2, integration_error="diag"),
    dict(order=3, integration_error="full"),
    dict(order=5, passes=2, integration_error="diag", tol=1e-6, n_min=2),
]


@pytest.mark.parametrize("seed,nx,nz", [(2, 1, 2), (3, 2, 2), (4, 3, 3), (6, 4, 1)])
def test_sif_variants_and_modified_ukf_equal_kalman_filter_on_linear_models(seed, nx, nz):
    """Degree 3 and 5 are exact for linear functions in every draw, so the mean of every draw is
    the same and the integration-error term is zero (to round-off): every variant, any pass
    structure or stopping rule, is the Kalman filter. So is the modified UT (its bias term
    (E[g] - g(m)) vanishes for linear g)."""
    F, H, Q, R, m0, P0 = random_linear(seed, nx, nz)
    traj = af.models.linear_gaussian(F, H, Q, R, m0, P0).simulate(n_runs=6, n_steps=20, rng=seed)
    gen = generic_model(F, H, Q, R, m0, P0)
    kf = af.KalmanFilter(gen, F=F, H=H).run(traj.z)
    for opts in SIF_VARIANTS:
        for n_iter in (1, 3):
            run = af.SIF(gen, n_iter=n_iter, seed=seed, **opts).run(traj.z)
            assert_runs_equal(run, kf, what=f"SIF {opts} n_iter={n_iter}")
    for kappa in (-0.5 * nx, 0.0, 2.0):
        if nx + kappa > 0:
            for form in ("modified", "auto"):
                assert_runs_equal(af.UKF(gen, kappa=kappa, form=form).run(traj.z), kf, what=f"UKF {form} kappa={kappa}")
    # order 1 (antithetic Monte Carlo) gets the mean of a linear map right but not its covariance
    one = af.SIF(gen, n_iter=3, seed=seed, order=1, on_indefinite="clip").run(traj.z)  # its Pxz, Pzz need not fit P
    assert np.abs(one.cov - kf.cov).max() > 1e-3 * np.abs(kf.cov).max()


def test_sif_integration_error_enters_p_pred_and_pzz():
    """P_pred = Cov[f] + Q + Vx and Pzz = Cov[h] + R + Vz, with V the rule's mean_var."""
    model = dataclasses.replace(af.models.coordinated_turn(), F=None)  # generic (stochastic) predict
    rng = np.random.default_rng(0)
    M = 4
    m = (model.m0 + rng.standard_normal((M, 4)) * 5).T.copy()
    P = np.repeat(model.P0[:, :, None] / 10, M, axis=2)
    with_v = af.SIF(model, n_iter=3, integration_error="diag")
    without = af.SIF(model, n_iter=3)
    rule = af.rules.StochasticIntegrationRule(order=3, integration_error="diag")
    f = with_v._wrap(model.f, 1)
    mo = rule.moments(f, m, P, 3, rng=np.random.default_rng(5), cross=False)
    _, Pv = with_v.predict_rl(m, P, 0, rng=np.random.default_rng(5))
    _, P0 = without.predict_rl(m, P, 0, rng=np.random.default_rng(5))
    np.testing.assert_allclose(Pv - P0, mo.mean_var, rtol=1e-9, atol=1e-12)
    assert np.all(np.diagonal(mo.mean_var) > 0)
    z = rng.uniform(-0.5, 0.5, (1, M))
    uv = with_v.update_rl(m, P, z, 0, rng=np.random.default_rng(6))
    u0 = without.update_rl(m, P, z, 0, rng=np.random.default_rng(6))
    h = with_v._wrap(model.h, 1)
    mo = rule.moments(h, m, P, 3, residual=with_v._residual_rl(), rng=np.random.default_rng(6))
    np.testing.assert_allclose(uv.Pzz - u0.Pzz, mo.mean_var, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(uv.Pxz, u0.Pxz)  # no cross term
    np.testing.assert_array_equal(uv.z_pred, u0.z_pred)


def test_sif_reports_iterations_spent():
    model = af.models.coordinated_turn()
    traj = model.simulate(8, 25, rng=9)
    run = af.SIF(model, n_iter=4, seed=1, on_indefinite="clip").run(traj.z, keep_pred=True)
    np.testing.assert_array_equal(run.info["n_iter_spent"], 4)
    np.testing.assert_array_equal(run.info["n_iter_spent_predict"], 0)  # CTM predicts exactly (F)
    sched = np.random.default_rng(0).choice([1, 2, 7], size=(8, 25))
    spent = af.SIF(model, seed=1, on_indefinite="clip").run(traj.z, params=sched).info["n_iter_spent"]
    np.testing.assert_array_equal(spent, sched)
    ref = af.SIF.reference(model, seed=1, on_indefinite="clip").run(traj.z)
    spent = ref.info["n_iter_spent"]
    assert spent.shape == (8, 25) and spent.min() >= 10 and spent.max() <= 20 and len(np.unique(spent)) > 1
    gen = dataclasses.replace(model, F=None)
    g = af.SIF(gen, n_iter=3, seed=1, passes=2, on_indefinite="clip").run(traj.z[:, :6])
    np.testing.assert_array_equal(g.info["n_iter_spent_predict"][:, 1:], 6)
    np.testing.assert_array_equal(g.info["n_iter_spent_predict"][:, 0], 0)
    assert af.UKF(model).run(traj.z[:, :3]).info == {}
    # the public update step reports it too (0 for a deterministic rule)
    u = af.SIF(model, n_iter=5, seed=1, tol=1e-3, n_min=2).update(run.x_pred[:, 2], run.P_pred[:, 2], traj.z[:, 2], 2)
    assert u.n_iter_spent.shape == (8,) and np.all((u.n_iter_spent >= 2) & (u.n_iter_spent <= 5))
    np.testing.assert_array_equal(af.UKF(model).update(run.x_pred[:, 2], run.P_pred[:, 2], traj.z[:, 2], 2).n_iter_spent, 0)


def test_sif_reference_preset_and_repr():
    model = af.models.coordinated_turn()
    ref = af.SIF.reference(model, seed=3)
    assert (ref.rule.order, ref.rule.passes, ref.rule.integration_error, ref.rule.tol, ref.rule.n_min) == (5, 2, "diag", 5e-4, 5)
    assert ref.predict_rule.tol == 5e-3 and ref.n_iter == 10
    assert repr(ref) == ("SIF(model='ctm', n_iter=10, order=5, passes=2, integration_error='diag', tol=0.0005, n_min=5, "
                         "tol_predict=0.005)")
    assert repr(af.SIF(model)) == "SIF(model='ctm', n_iter=10)"  # the default filter's name is unchanged
    assert repr(af.UKF(model, kappa=-1.0, form="auto")) == "UKF(model='ctm', kappa=-1, form='auto')"
    with pytest.raises(ValueError, match="form must be one of"):
        af.UKF(model, form="mod")
    with pytest.raises(ValueError, match="order must be one of"):
        af.SIF(model, order=7)


def test_update_rl_tile_gives_every_candidate_the_same_draws():
    """The MDP's tiled evaluation of all grid values: with tile=G the candidate of grid value g
    for run j is exactly the update the filter makes when run j takes g (same rng)."""
    model = af.models.coordinated_turn()
    traj = model.simulate(5, 4, rng=12)
    for sif in (af.SIF(model, seed=4), af.SIF.reference(model, seed=4)):
        run = sif.run(traj.z[:, :3], keep_pred=True)
        m, P = run.x_pred[:, 2].T.copy(), np.moveaxis(run.P_pred[:, 2], 0, -1).copy()
        z = traj.z[:, 2].T.copy()
        grid = np.array([1.0, 3.0, 10.0])
        G, M = grid.size, m.shape[1]
        tile = lambda a: np.concatenate([a] * G, axis=-1)
        theta = np.repeat(grid, M)
        cand = sif.update_rl(tile(m), tile(P), tile(z), 2, theta, rng=sif.rng(1, 2, 7), tile=G)
        indep = sif.update_rl(tile(m), tile(P), tile(z), 2, theta, rng=sif.rng(1, 2, 7))
        for g, th in enumerate(grid):
            one = sif.update_rl(m, P, z, 2, th, rng=sif.rng(1, 2, 7))
            sl = slice(g * M, (g + 1) * M)
            for name in ("z_pred", "Pzz", "Pxz", "x_filt", "P_filt", "nis", "n_iter_spent"):
                np.testing.assert_allclose(getattr(cand, name)[..., sl], getattr(one, name), rtol=1e-12, atol=1e-300, err_msg=name)
        assert np.all(indep.nis[M:] != cand.nis[M:])  # without tile every copy draws afresh
    # a deterministic rule ignores tile (but checks it)
    ukf = af.UKF(model)
    u1 = ukf.update_rl(np.tile(m, 2), np.tile(P, 2), np.tile(z, 2), 2, 0.0, tile=2)
    np.testing.assert_array_equal(u1.x_filt, ukf.update_rl(np.tile(m, 2), np.tile(P, 2), np.tile(z, 2), 2, 0.0).x_filt)
    with pytest.raises(ValueError, match="must divide"):
        ukf.update_rl(np.tile(m, 2), np.tile(P, 2), np.tile(z, 2), 2, 0.0, tile=3)


def test_modified_ukf_on_ctm_with_negative_kappa():
    """kappa = -2 on the CTM: the standard form loses definiteness (FilterError, or repairs with
    clip); the modified form ("auto") never does and stays finite; kappa >= 0 is unchanged."""
    model = af.models.coordinated_turn()
    traj = model.simulate(200, 150, rng=13)
    with pytest.raises(af.FilterError, match="not positive definite"):
        af.UKF(model, kappa=-2.0).run(traj.z)
    std = af.UKF(model, kappa=-2.0, on_indefinite="clip").run(traj.z)
    auto = af.UKF(model, kappa=-2.0, form="auto").run(traj.z)
    assert std.n_repairs > 0 and auto.n_repairs == 0
    assert np.isfinite(auto.mean).all() and np.all(np.linalg.eigvalsh(auto.cov) > 0)
    anees = lambda r: af.metrics.anees(traj.x, r.mean, r.cov, on_indefinite="solve").mean()  # noqa: E731  (clipped runs store indefinite P)
    assert anees(auto) < anees(std)
    for kappa in (0.0, 1.0):
        np.testing.assert_array_equal(af.UKF(model, kappa=kappa, form="auto").run(traj.z[:20]).cov,
                                      af.UKF(model, kappa=kappa).run(traj.z[:20]).cov)


# ------------------------------------------------ the Filter interface (adaptfilt.filters)
def _linear():
    return af.models.linear_gaussian(F=[[0.9, 0.1], [0.0, 0.95]], H=[[1.0, 0.0]], Q=np.eye(2) * 0.1, R=[[0.5]],
                                     m0=[0.0, 1.0], P0=np.eye(2))


def _every_filter():
    """One of every filter class of the library, each on a model it is made for: ``(filter, run kwargs)``."""
    from adaptfilt.kalmannet import KalmanNet
    from adaptfilt.particles import ParticleCountFilter

    ungm, ctm, lin = af.models.ungm(), af.models.coordinated_turn(), _linear()
    return {
        "GaussianAssumedFilter": (af.GaussianAssumedFilter(ungm, af.rules.UnscentedRule(), param=2.0), {}),
        "UKF": (af.UKF(ctm, kappa=0.0), {}),
        "SIF": (af.SIF(ungm, n_iter=4, seed=3), {}),
        "CKF": (af.CKF(ctm), {}),
        "KalmanFilter": (af.KalmanFilter(lin), {}),
        "PointMassFilter": (af.PointMassFilter(ungm, grid=np.linspace(-45, 45, 401)), {}),
        "BootstrapParticleFilter": (af.BootstrapParticleFilter(ctm, n_particles=300, seed=[24, 0, 300]), {}),
        "ParticleCountFilter": (ParticleCountFilter(ungm, seed=1, backend="numpy"), {"n_particles": 100}),
        "KalmanNet": (KalmanNet(lin, seed=0), {}),
        "KalmanNet (Bayesian)": (KalmanNet(lin, dropout=0.2, n_samples=3, seed=0), {}),
    }


@pytest.mark.parametrize("name", list(_every_filter()))
def test_every_filter_of_the_library_meets_the_filter_interface(name):
    filt, kw = _every_filter()[name]
    assert isinstance(filt, af.Filter)
    af.check_filter(filt, **kw)


def test_every_filter_class_is_checked():
    """Every class of the library with a ``run(z) -> FilterRun`` and a ``model`` is in the list above."""
    import inspect

    from adaptfilt import exact, gaf, kalmannet, particles

    classes = {c.__name__ for m in (gaf, exact, particles, kalmannet) for c in vars(m).values()
               if inspect.isclass(c) and c.__module__ == m.__name__ and callable(getattr(c, "run", None))
               and "FilterRun" in str(inspect.signature(c.run).return_annotation)}
    assert classes == {n.split(" ")[0] for n in _every_filter()}


def test_what_a_filter_without_a_covariance_returns():
    """Plain KalmanNet: cov and nis all NaN (the declared "none"); the Bayesian variant has a covariance."""
    filt, _ = _every_filter()["KalmanNet"]
    run = filt.run(_linear().simulate(3, 5, rng=0).z)
    assert not af.filters.has_covariance(run) and not af.filters.has_nis(run) and np.isnan(run.params).all()
    bayes, _ = _every_filter()["KalmanNet (Bayesian)"]
    assert af.filters.has_covariance(bayes.run(_linear().simulate(3, 5, rng=0).z))


class _Stand(af.KalmanFilter):
    """A Kalman filter whose run one test breaks at a time."""

    def __init__(self, model, spoil=None):
        super().__init__(model)
        self.spoil = spoil

    def __repr__(self):
        return "Stand()"

    def run(self, z):
        r = super().run(z)
        return self.spoil(r, z) if self.spoil else r


def _replace(**kw):
    return lambda r, z: dataclasses.replace(r, **{k: v(r) for k, v in kw.items()})


_draws = np.random.default_rng(5)
BROKEN = {
    "a tuple": (lambda r, z: (r.mean, r.cov), "must return a FilterRun"),
    "a wrong mean shape": (_replace(mean=lambda r: r.mean[:, 1:]), r"mean must have shape \(4, 6, 2\)"),
    "a NaN estimate": (_replace(mean=lambda r: np.where(np.arange(6)[:, None] == 3, np.nan, r.mean)), "mean is not finite"),
    "a covariance partly NaN": (_replace(cov=lambda r: np.where(np.arange(6)[:, None, None] == 2, np.nan, r.cov)),
                                "cov must be finite, or all NaN"),
    "a covariance not symmetric": (_replace(cov=lambda r: r.cov + np.array([[0.0, 1.0], [0.0, 0.0]])), "not symmetric"),
    "a negative variance": (_replace(cov=lambda r: r.cov - 10 * np.eye(2)), "not positive semi-definite"),
    "a NIS without a covariance": (_replace(cov=lambda r: np.full_like(r.cov, np.nan)), "nis must be all NaN"),
    "a negative NIS": (_replace(nis=lambda r: -r.nis), "nis must be finite and non-negative"),
    "a log-likelihood partly NaN": (_replace(loglik=lambda r: np.where(np.arange(6) == 0, np.nan, r.loglik)),
                                    "loglik must be finite, or all NaN"),
    "draws that move on": (_replace(mean=lambda r: r.mean + _draws.standard_normal(r.mean.shape)), "twice gave different mean"),
    "a written input": (lambda r, z: (z.__setitem__(..., 0.0), r)[1], "changed z"),
}


@pytest.mark.parametrize("what", list(BROKEN))
def test_check_filter_rejects_a_broken_filter_naming_the_rule(what):
    spoil, message = BROKEN[what]
    with pytest.raises(af.filters.FilterCheckError, match=message):
        af.check_filter(_Stand(_linear(), spoil))


def test_check_filter_rejects_missing_members_a_default_repr_another_model_and_a_moving_seed():
    check = af.filters.FilterCheckError
    with pytest.raises(check, match="missing member.*run"):
        af.check_filter(type("NoRun", (), {"model": _linear()})())
    with pytest.raises(check, match="repr is"):
        af.check_filter(type("Plain", (_Stand,), {"__repr__": object.__repr__})(_linear()))
    with pytest.raises(check, match="nx = 2, the model it is checked on 1"):
        af.check_filter(_Stand(_linear()), model=af.models.ungm())
    declared = _Stand(_linear())
    declared.param_name = "kappa"
    with pytest.raises(check, match="declares param_name = 'kappa', but run.*params is not finite"):
        af.check_filter(declared)
    # a particle filter seeded with a Generator draws on from it: the second run differs
    pf = af.BootstrapParticleFilter(af.models.coordinated_turn(), n_particles=200, seed=np.random.default_rng(0))
    with pytest.raises(check, match="twice gave different mean"):
        af.check_filter(pf)
