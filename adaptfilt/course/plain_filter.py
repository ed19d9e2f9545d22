r"""Algorithm 1 and its moment rules for one run, written plainly: what chapter 2 shows on the page.

The library's :class:`~adaptfilt.gaf.GaussianAssumedFilter` and its rules (:mod:`adaptfilt.rules`)
compute the same numbers for thousands of runs at once (the run axis last, Cholesky solves, compiled
kernels that keep numpy's bits, covariance checks and repairs); that engineering hides the few lines of
mathematics the chapter teaches. These functions are those lines for one run, and
``tests/test_plain_filter.py`` holds them equal to the library (to rounding):

* :func:`weighted_moments`: :math:`\mathrm{E}[\mathbf g]`, :math:`\mathrm{Cov}[\mathbf g]` and
  :math:`\mathrm{Cov}[\mathbf x, \mathbf g]` from weighted points, the arithmetic every rule shares;
* :func:`unscented_points`: Julier's sigma points and weights (parameter :math:`\kappa`);
* :func:`sir_points` and :func:`sir_moments`: one draw of the degree-3 stochastic integration rule,
  and :math:`N_\text{it}` draws pooled (the one-pass SIR of ``af.SIF``'s defaults);
* :func:`gaussian_filter`: Algorithm 1 (update, then predict) with any of these rules.

Points are rows: ``X (S, n)`` holds ``S`` points, the centre first; weights ``w (S,)``.

Example
-------
>>> import numpy as np, adaptfilt as af
>>> model = af.models.ungm()
>>> z = model.simulate(n_runs=1, n_steps=20, rng=np.random.default_rng(0)).z[0]   # (T, nz)
>>> means, covs = gaussian_filter(model, lambda m, P: unscented_points(m, P, 2.0), z)
>>> lib = af.UKF(model, kappa=2.0).run(z[None])
>>> bool(np.allclose(means, lib.mean[0]) and np.allclose(covs, lib.cov[0]))
True
"""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["weighted_moments", "unscented_points", "sir_points", "sir_moments", "gaussian_filter"]


def weighted_moments(g: Callable, X: np.ndarray, w: np.ndarray, diff: Callable = np.subtract):
    """``E[g(x)]``, ``Cov[g(x)]`` and ``Cov[x, g(x)]`` from the points ``X (S, n)`` (centre first)
    and their weights ``w (S,)``; ``g`` maps the points to ``(S, ng)`` at once, and ``diff(a, b)``
    is ``a - b`` (wrapped for an angle, ``model.diff_z``)."""
    Y = g(X)
    D = diff(Y, Y[0])                    # deviations from the centre's value (small for an angle)
    mean = Y[0] + w @ D
    dY, dX = D - w @ D, X - w @ X        # deviations from the means
    return mean, (w[:, None] * dY).T @ dY, (w[:, None] * dX).T @ dY


def unscented_points(m: np.ndarray, P: np.ndarray, kappa: float):
    """Julier's ``2n + 1`` sigma points of ``N(m, P)`` and their weights."""
    n = m.size
    A = np.sqrt(n + kappa) * np.linalg.cholesky(P).T   # row j: sqrt(n + kappa) L e_j
    X = np.vstack([m, m + A, m - A])
    w = np.full(2 * n + 1, 0.5 / (n + kappa))
    w[0] = kappa / (n + kappa)
    return X, w


def sir_points(m: np.ndarray, P: np.ndarray, rng: np.random.Generator):
    """One draw of the degree-3 stochastic integration rule: ``2n + 1`` points and weights."""
    n = m.size
    G, rho2 = rng.standard_normal((n, n)), rng.chisquare(n + 2)
    U, R = np.linalg.qr(G)
    U = U * np.sign(np.diag(R))          # Gram-Schmidt on Gaussian columns: a Haar rotation
    A = np.sqrt(rho2) * (np.linalg.cholesky(P) @ U).T  # row j: rho L U e_j
    X = np.vstack([m, m + A, m - A])
    w = np.full(2 * n + 1, 0.5 / rho2)
    w[0] = 1 - n / rho2
    return X, w


def sir_moments(g: Callable, m: np.ndarray, P: np.ndarray, n_iter: int, rng: np.random.Generator,
                diff: Callable = np.subtract):
    """The SIR's moments: ``n_iter`` draws pooled, each with weight ``1 / n_iter`` (the mean is
    the average of the draws' means, the covariances are taken about it)."""
    draws = [sir_points(m, P, rng) for _ in range(n_iter)]
    X = np.vstack([X for X, _ in draws])
    w = np.concatenate([w for _, w in draws]) / n_iter
    return weighted_moments(g, X, w, diff)


def gaussian_filter(model, points: Callable, z: np.ndarray):
    """Algorithm 1 on one run's measurements ``z (T, nz)``: the filtering means ``(T, nx)`` and
    covariances ``(T, nx, nx)``. ``points(m, P) -> (X, w)`` is the moment rule."""
    x, P = model.m0, model.P0            # the prior of the first measured state
    means, covs = [], []
    for t, z_t in enumerate(z):
        # update: the predicted measurement's moments (5)-(7), the gain, the mean, the covariance
        h = lambda X: model.h(X, t + 1)  # noqa: E731
        z_pred, Pzz, Pxz = weighted_moments(h, *points(x, P), model.diff_z)
        Pzz = Pzz + model.R
        K = np.linalg.solve(Pzz, Pxz.T).T            # K = Pxz Pzz^-1, without the inverse
        x, P = x + K @ model.diff_z(z_t, z_pred), P - K @ Pzz @ K.T
        means.append(x)
        covs.append(P)
        # predict to the next step
        x, P_f, _ = weighted_moments(lambda X: model.f(X, t + 1), *points(x, P))
        P = P_f + model.Q
    return np.array(means), np.array(covs)
