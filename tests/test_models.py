"""State-space models: validation, the paper's equations, time convention, simulation."""
import dataclasses

import numpy as np
import pytest
from scipy.linalg import expm

import adaptfilt as af
from adaptfilt.models import ct_matrices


def scalar(**kw):
    args = dict(f=lambda x, k: 0.9 * x, h=lambda x, k: np.sin(x), Q=[[0.1]], R=[[0.01]], m0=[0.0], P0=[[1.0]])
    args.update(kw)
    return af.StateSpaceModel(**args)


def two_d(**kw):
    args = dict(f=lambda x, k: x, h=lambda x, k: x[..., :1], Q=np.eye(2), R=[[1.0]], m0=[0.0, 0.0], P0=np.eye(2))
    args.update(kw)
    return af.StateSpaceModel(**args)


@pytest.mark.parametrize(
    "kw,match",
    [
        (dict(Q=np.eye(3)), r"Q must be 2x2"),
        (dict(P0=np.eye(1)), r"P0 must be 2x2"),
        (dict(m0=[0.0, 0.0, 0.0], P0=np.eye(3)), r"Q must be 3x3"),
        (dict(m0=[[0.0, 0.0]]), r"m0 must be a finite vector"),
        (dict(m0=[0.0, np.nan]), r"m0 must be a finite vector"),
        (dict(Q=[[1.0, 0.5], [0.0, 1.0]]), r"Q must be symmetric"),
        (dict(R=[[1.0, 0.2], [0.1, 1.0]], h=lambda x, k: x), r"R must be symmetric"),
        (dict(P0=[[1.0, 2.0], [2.0, 1.0]]), r"P0 must be positive definite"),
        (dict(Q=np.zeros((2, 2))), r"Q must be positive definite"),
        (dict(R=[[-1.0]]), r"R must be positive definite"),
        (dict(Q=[[1.0, np.inf], [np.inf, 1.0]]), r"Q has non-finite entries"),
        (dict(R=[[np.nan]]), r"R has non-finite entries"),
        (dict(Q=np.ones((2, 3))), r"Q must be a square matrix"),
        (dict(f=lambda x, k: x[..., :1]), r"f\(x, k\) must map a batch x of shape \(\.\.\., 2\) to \(\.\.\., 2\)"),
        (dict(f=lambda x, k: np.sum(x)), r"f\(x, k\) must map"),
        (dict(h=lambda x, k: x), r"h\(x, k\) must map a batch x of shape \(\.\.\., 2\) to \(\.\.\., 1\)"),
        (dict(h=lambda x, k: x[0]), r"h\(x, k\) must map"),
        (dict(R=np.eye(3)), r"h\(x, k\) must map a batch x of shape \(\.\.\., 2\) to \(\.\.\., 3\)"),  # R sets nz
        (dict(f="not callable"), r"f and h must be callables"),
        (dict(F=np.eye(3)), r"F must be 2x2"),
        (dict(H=np.eye(2)), r"H must be 1x2"),
        (dict(residual=lambda a, b: (a - b)[..., 0]), r"residual\(a, b\) must return the shape of a"),
        (dict(n_steps=0), r"n_steps must be positive"),
    ],
)
def test_model_validation_names_the_argument(kw, match):
    with pytest.raises(ValueError, match=match):
        two_d(**kw)


def test_valid_model_properties():
    m = two_d(R=[[2.0]])
    assert (m.nx, m.nz) == (2, 1)
    assert m.P0.dtype == float and m.R.shape == (1, 1)
    s = scalar(Q=0.1, R=0.01, P0=1.0)  # scalars are promoted to 1x1
    assert s.Q.shape == (1, 1) and s.nz == 1


def test_ungm_equations():
    model = af.models.ungm()
    x = np.array([[-3.0], [0.0], [2.5]])
    for k in (1, 7, 250):
        expect_f = 0.5 * x + 25 * x / (1 + x**2) + 8 * np.cos(0.05 * k)
        np.testing.assert_allclose(model.f(x, k), expect_f, rtol=1e-15)
        np.testing.assert_allclose(model.h(x, k), x**2 / 20, rtol=1e-15)
    assert model.Q[0, 0] == 1.0 and model.R[0, 0] == 0.1 and model.P0[0, 0] == 5.0 and model.m0[0] == 0.0
    assert model.n_steps == 500 and model.F is None and model.H is None


def test_ctm_equations():
    model = af.models.coordinated_turn()
    # F is the exact discretisation of the continuous coordinated turn, dx/dt = A x
    w, dt = 0.5, 1.0
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    A[1, 3], A[3, 1] = -w, w
    np.testing.assert_allclose(model.F, expm(A * dt), atol=1e-12)
    np.testing.assert_allclose(model.Q, np.kron(np.eye(2), [[1 / 3, 1 / 2], [1 / 2, 1.0]]), rtol=1e-15)
    np.testing.assert_allclose(model.m0, [80, 0, 0, 20])
    np.testing.assert_allclose(model.P0, np.diag([1e3, 1e2, 1e3, 1e2]))
    assert model.R[0, 0] == 0.04 and model.n_steps == 150
    x = np.array([[1.0, 5.0, 1.0, 0.0], [-1.0, 0.0, -1e-3, 0.0], [0.0, 0.0, 2.0, 0.0]])
    np.testing.assert_allclose(model.h(x, 3)[:, 0], [np.pi / 4, -np.pi + 1e-3, np.pi / 2], rtol=1e-6)
    np.testing.assert_allclose(model.f(x, 1), x @ model.F.T)
    # the residual wraps: 3.1 - (-3.1) is -0.083, not 6.2
    np.testing.assert_allclose(model.diff_z(np.array([3.1]), np.array([-3.1])), [6.2 - 2 * np.pi])
    # other parameters: dt = 2, omega = 0.1
    F, Q = ct_matrices(0.1, 2.0, 3.0)
    A[1, 3], A[3, 1] = -0.1, 0.1
    np.testing.assert_allclose(F, expm(A * 2.0), atol=1e-12)
    np.testing.assert_allclose(Q[:2, :2], 3.0 * np.array([[8 / 3, 2.0], [2.0, 2.0]]))


def test_linear_gaussian_declares_F_H():
    F, H = [[1.0, 1.0], [0.0, 1.0]], [[1.0, 0.0]]
    m = af.models.linear_gaussian(F, H, Q=np.eye(2), R=[[1.0]], m0=[0, 0], P0=np.eye(2))
    x = np.array([[1.0, 2.0]])
    np.testing.assert_allclose(m.f(x, 1), [[3.0, 2.0]])
    np.testing.assert_allclose(m.h(x, 1), [[1.0]])
    assert m.F.shape == (2, 2) and m.H.shape == (1, 2)


def test_time_convention():
    """f(x, k) maps x_k to x_{k+1}; h(x, k) gives z_k; array index t is k = t + 1."""
    m = af.StateSpaceModel(
        f=lambda x, k: np.full_like(x, float(k)), h=lambda x, k: np.full_like(x, 100.0 * k),
        Q=[[1e-12]], R=[[1e-12]], m0=[-5.0], P0=[[1e-12]],
    )
    tr = m.simulate(n_runs=2, n_steps=6, rng=0)
    np.testing.assert_allclose(tr.x[:, :, 0], [[-5, 1, 2, 3, 4, 5]] * 2, atol=1e-4)
    np.testing.assert_allclose(tr.z[:, :, 0], [[100, 200, 300, 400, 500, 600]] * 2, atol=1e-4)


def test_simulate_statistics():
    F = np.array([[0.9, 0.2], [-0.1, 0.8]])
    H = np.array([[1.0, -1.0], [0.5, 2.0]])
    Q = np.array([[0.5, 0.1], [0.1, 0.3]])
    R = np.array([[0.2, 0.05], [0.05, 0.1]])
    P0 = np.array([[2.0, 0.3], [0.3, 1.0]])
    m = af.models.linear_gaussian(F, H, Q, R, m0=[1.0, -2.0], P0=P0)
    M = 20000
    tr = m.simulate(n_runs=M, n_steps=3, rng=np.random.default_rng(1))
    assert tr.x.shape == (M, 3, 2) and tr.z.shape == (M, 3, 2)
    tol = lambda C: 5 * np.sqrt((np.diag(C)[:, None] * np.diag(C)[None, :] + C**2) / M)
    x0 = tr.x[:, 0]
    assert np.all(np.abs(x0.mean(0) - m.m0) < 5 * np.sqrt(np.diag(P0) / M))
    assert np.all(np.abs(np.cov(x0.T) - P0) < tol(P0))
    w = tr.x[:, 2] - tr.x[:, 1] @ F.T
    assert np.all(np.abs(w.mean(0)) < 5 * np.sqrt(np.diag(Q) / M))
    assert np.all(np.abs(np.cov(w.T) - Q) < tol(Q))
    v = tr.z[:, 1] - tr.x[:, 1] @ H.T
    assert np.all(np.abs(np.cov(v.T) - R) < tol(R))


def test_simulate_seeds():
    model = af.models.coordinated_turn()
    a = model.simulate(5, 20, rng=3)
    b = model.simulate(5, 20, rng=np.random.default_rng(3))
    c = model.simulate(5, 20, rng=4)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.z, b.z)
    assert np.all(a.x != c.x) and np.all(a.z != c.z)
    assert model.simulate(2, rng=0).x.shape == (2, 150, 4)  # the model's horizon by default
    sub = a[1:3]
    assert sub.n_runs == 2 and sub.n_steps == 20
    np.testing.assert_array_equal(sub.z, a.z[1:3])


def test_simulate_argument_errors():
    with pytest.raises(ValueError, match="n_steps must be a positive integer"):
        scalar().simulate(3)  # no default horizon
    with pytest.raises(ValueError, match="n_runs must be a positive integer"):
        scalar().simulate(0, 5)


def test_bearing_measurement_noise_is_wrapped_consistently():
    """Simulated bearings near the negative x-axis differ from atan2 by the noise modulo 2 pi."""
    model = dataclasses.replace(af.models.coordinated_turn(), m0=np.array([-80.0, 0.0, 0.0, 0.0]), P0=np.eye(4))
    tr = model.simulate(4000, 2, rng=0)
    v = model.diff_z(tr.z, model.h(tr.x, 1))
    assert np.abs(v).max() < 1.5  # wrapped difference is the small noise
    assert abs(v.var() - 0.04) < 0.005
