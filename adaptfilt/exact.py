r"""Exact references: the Kalman filter, the point-mass (grid) filter and the bootstrap particle filter.

They are written independently of the Gaussian-assumed filter (plain
``(M, n, n)`` numpy; the only shared code is the result container
:class:`~adaptfilt.filters.FilterRun`), so that agreement with them is evidence.

* :class:`KalmanFilter`: linear-Gaussian models; every moment rule must agree with it.
* :class:`PointMassFilter`: scalar models with additive Gaussian noise; the
  Bayes-optimal filter up to grid resolution, e.g. the accuracy floor of UNGM.
* :class:`BootstrapParticleFilter`: any model with additive Gaussian noise; the
  Bayes-optimal filter up to Monte-Carlo error in the number of particles, e.g.
  the reference posterior of the bearing-only coordinated turn.
* :func:`bayes_floor`: the point-mass filter on the first runs of an evaluation, the floor under
  any RMSE claim on a scalar model (the one floor of the reproduction, the studies and the course).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from adaptfilt import metrics
from adaptfilt.filters import FilterRun
from adaptfilt.models import StateSpaceModel

__all__ = ["KalmanFilter", "PointMassFilter", "BootstrapParticleFilter", "BayesFloor", "bayes_floor",
           "UNGM_FLOOR_GRID", "UNGM_STUDY_FLOOR_GRID"]

#: The UNGM floors' grids on -45..45 (the point-mass filter raises when probability mass reaches an edge):
#: 901 points for the reproduction's floor (``data/results/ungm-floor.json``) and the course, 1801 for the
#: studies' (the learned gain, the particle count). Each stored floor was computed on its grid and records it.
UNGM_FLOOR_GRID = np.linspace(-45.0, 45.0, 901)
UNGM_STUDY_FLOOR_GRID = np.linspace(-45.0, 45.0, 1801)


class KalmanFilter:
    r"""The Kalman filter for ``x_{k+1} = F x_k + w_k``, ``z_k = H x_k + v_k``.

    .. math::
        \hat x_{k|k-1} = F \hat x_{k-1|k-1},\quad P_{k|k-1} = F P_{k-1|k-1} F^T + Q,\quad
        S = H P_{k|k-1} H^T + R,\quad K = P_{k|k-1} H^T S^{-1},

    .. math::
        \hat x_{k|k} = \hat x_{k|k-1} + K (z_k - H \hat x_{k|k-1}),\quad
        P_{k|k} = (I - K H) P_{k|k-1} (I - K H)^T + K R K^T \;\text{(Joseph form)}.

    ``F``, ``H`` default to the model's.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.linear_gaussian(F=[[1.0]], H=[[1.0]], Q=[[0.1]], R=[[1.0]], m0=[0.0], P0=[[1.0]])
    >>> traj = model.simulate(n_runs=10, n_steps=20, rng=0)
    >>> run = af.KalmanFilter(model).run(traj.z)
    """

    def __init__(self, model: StateSpaceModel, F=None, H=None):
        F = model.F if F is None else np.atleast_2d(np.asarray(F, dtype=float))
        H = model.H if H is None else np.atleast_2d(np.asarray(H, dtype=float))
        if F is None or H is None:
            raise ValueError(f"the Kalman filter needs a linear model: model {model.name!r} has no F/H and none were given")
        self.model, self.F, self.H = model, F, H

    def __repr__(self) -> str:
        return f"KalmanFilter(model={self.model.name!r})"

    def run(self, z) -> FilterRun:
        """Filter ``z (M, T, nz)``."""
        model, F, H, Q, R = self.model, self.F, self.H, self.model.Q, self.model.R
        z = np.asarray(z, dtype=float)
        if z.ndim == 2 and model.nz == 1:
            z = z[..., None]
        M, T, _ = z.shape
        nx = model.nx
        x = np.tile(model.m0, (M, 1))
        P = np.tile(model.P0, (M, 1, 1))
        mean, cov = np.empty((M, T, nx)), np.empty((M, T, nx, nx))
        nis, ll = np.empty((M, T)), np.empty((M, T))
        I = np.eye(nx)
        for t in range(T):
            if t:
                x = x @ F.T
                P = F @ P @ F.T + Q
            S = H @ P @ H.T + R
            K = np.linalg.solve(S, H @ P).transpose(0, 2, 1)  # P H^T S^-1 (S, P symmetric)
            y = z[:, t] - x @ H.T
            Sy = np.linalg.solve(S, y[..., None])[..., 0]
            nis[:, t] = (y * Sy).sum(-1)
            ll[:, t] = -0.5 * (nis[:, t] + np.linalg.slogdet(S)[1] + model.nz * np.log(2 * np.pi))
            x = x + (K @ y[..., None])[..., 0]
            A = I - K @ H
            P = A @ P @ A.transpose(0, 2, 1) + K @ R @ K.transpose(0, 2, 1)
            mean[:, t], cov[:, t] = x, P
        return FilterRun(mean=mean, cov=cov, nis=nis, loglik=ll, params=np.full((M, T), np.nan))


class PointMassFilter:
    r"""Point-mass (grid) filter for scalar models with additive Gaussian noise.

    The density is kept on a fixed grid ``x_1 < ... < x_N`` (spacing
    ``dx``). Chapman-Kolmogorov and Bayes' rule become

    .. math::
        p_{k|k-1}(x_i) = \sum_j N(x_i; f(x_j, k-1), Q)\, p_{k-1|k-1}(x_j)\, dx,\qquad
        p_{k|k}(x_i) \propto N(z_k; h(x_i, k), R)\, p_{k|k-1}(x_i),

    the prediction being one matrix product for all runs at once. The
    filtering mean is the MMSE estimate: for UNGM the Bayes floor of any RMSE.

    ``run`` raises ``ValueError`` when more than ``edge_tol`` of the
    probability mass sits in the outer 1% of the grid (the grid is too small).

    Transition and likelihood values below ``negligible`` (default ``1e-150``) are set to zero. Their
    products with the density's far tails underflow to subnormal numbers, which the CPU multiplies
    several times slower (the matrix product of the prediction took 38 ms per 250 runs on UNGM's
    densities against 8 ms on random numbers), and a term of relative size ``1e-150`` cannot change a
    density normalised to 1 at double precision: on 500 UNGM runs of 500 steps the means and variances
    are bit for bit those with ``negligible=0`` (every value kept), in half the CPU time
    (``benchmarks/bench_floor.py``; ``tests/test_exact.py`` checks it). A coarser cut is allowed (up
    to ``1e-6``) and changes the numbers: ``1e-20`` moved means by about ``1e-22``, ``1e-16`` by ``1e-13``.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.ungm()
    >>> traj = model.simulate(n_runs=20, n_steps=50, rng=0)
    >>> pmf = af.PointMassFilter(model, grid=np.linspace(-45, 45, 901))
    >>> run = pmf.run(traj.z)
    """

    def __init__(self, model: StateSpaceModel, grid=None, edge_tol: float = 1e-4, negligible: float = 1e-150):
        if model.nx != 1 or model.nz != 1:
            raise ValueError(f"the point-mass filter here is for scalar models (nx = nz = 1); {model.name!r} has nx={model.nx}, nz={model.nz}")
        if grid is None:
            s0 = float(np.sqrt(model.P0[0, 0]))
            grid = np.linspace(model.m0[0] - 10 * s0, model.m0[0] + 10 * s0, 801)
        grid = np.asarray(grid, dtype=float)
        if grid.ndim != 1 or grid.size < 3 or not np.all(np.diff(grid) > 0):
            raise ValueError("grid must be an increasing 1-D array of at least 3 points")
        d = np.diff(grid)
        if not np.allclose(d, d[0], rtol=1e-8):
            raise ValueError("grid must be equally spaced")
        if not (np.isfinite(negligible) and 0.0 <= negligible < 1e-6):
            raise ValueError(f"negligible must be in [0, 1e-6), got {negligible}")
        self.model, self.grid, self.dx, self.edge_tol = model, grid, float(d[0]), edge_tol
        self.negligible = float(negligible)

    def __repr__(self) -> str:
        g = self.grid
        return f"PointMassFilter(model={self.model.name!r}, grid=np.linspace({g[0]:g}, {g[-1]:g}, {g.size}))"

    def _gauss(self, r, var):
        g = np.exp(-0.5 * r * r / var) / np.sqrt(2 * np.pi * var)
        if self.negligible:
            g[g < self.negligible] = 0.0  # see the class docstring: products below ~1e-300 are subnormal, slow
        return g

    def run(self, z, keep_density_at: tuple[int, ...] = (), chunk: int | None = None) -> FilterRun:
        """Filter ``z (M, T, 1)``; ``keep_density_at`` lists steps whose
        filtering densities ``(M, N)`` go into ``run.info["density"][t]``.

        ``chunk``: filter the runs in groups of this many (the last may be smaller), each group's
        arrays ``(N, chunk)`` on their own, as separate calls ``run(z[a:a + chunk])`` would, with the
        same numbers (every operation on the same operands and shapes), but the transition kernel
        (``N x N``, the same for every run) computed once per step for all groups. None: one group."""
        model, x, dx = self.model, self.grid, self.dx
        z = np.asarray(z, dtype=float)
        if z.ndim == 3:
            z = z[..., 0]
        M, T = z.shape
        size = M if chunk is None else int(chunk)
        if size < 1:
            raise ValueError(f"chunk must be a positive number of runs, got {chunk!r}")
        groups = [(a, min(a + size, M)) for a in range(0, M, size)] or [(0, 0)]
        Q, R = float(model.Q[0, 0]), float(model.R[0, 0])
        p0 = self._gauss(x - model.m0[0], float(model.P0[0, 0]))[:, None]
        ps = [p0 * np.ones((1, b - a)) for a, b in groups]  # (N, runs of the group)
        edge = max(1, x.size // 100)
        mean, var, ll = np.empty((M, T)), np.empty((M, T)), np.empty((M, T))
        dens = {}
        for t in range(T):
            if t:
                fx = model.f(x[:, None], t)[:, 0]
                Kt = self._gauss(x[:, None] - fx[None, :], Q) * dx  # Kt[i, j] = p(x_i | x_j)
            hx = model.h(x[:, None], t + 1)[:, 0]
            for k, (a, b) in enumerate(groups):
                p = ps[k]
                if t:
                    p = Kt @ p
                lik = self._gauss(z[a:b, t][None, :] - hx[:, None], R)
                p = lik * p
                c = p.sum(0) * dx
                if not (c > 0).all():
                    raise ValueError(f"point-mass filter lost all mass at step t={t} in runs {a + np.flatnonzero(~(c > 0))[:10]}: widen the grid")
                ll[a:b, t] = np.log(c)
                p = p / c
                mass_edge = (p[:edge].sum(0) + p[-edge:].sum(0)) * dx
                if (mass_edge > self.edge_tol).any():
                    r = a + np.flatnonzero(mass_edge > self.edge_tol)
                    raise ValueError(f"point-mass filter: probability mass {mass_edge.max():.2g} at the grid's edge at step t={t} (runs {r[:10]}); widen the grid")
                mean[a:b, t] = (x[:, None] * p).sum(0) * dx
                var[a:b, t] = ((x[:, None] - mean[a:b, t]) ** 2 * p).sum(0) * dx
                ps[k] = p
            if t in keep_density_at:
                dens[t] = np.concatenate([p.T for p in ps]) if len(ps) > 1 else ps[0].T.copy()
        return FilterRun(
            mean=mean[..., None], cov=var[..., None, None], nis=np.full((M, T), np.nan), loglik=ll,
            params=np.full((M, T), np.nan), info={"density": dens, "grid": x},
        )


class BootstrapParticleFilter:
    r"""The bootstrap particle filter (Gordon, Salmond and Smith, 1993) for models with
    additive Gaussian noise, ``x_{k+1} = f(x_k) + w_k``, ``z_k = h(x_k) + v_k``.

    Each run carries ``N`` particles :math:`\mathbf x^{(i)}` drawn from the prior
    :math:`\mathcal N(\mathbf m_0, \mathbf P_0)`; at every step they are propagated through the
    dynamics with fresh process noise (from the second step on), weighted by the likelihood

    .. math::
        w^{(i)} \propto w^{(i)}_{-}\,\mathcal N\big(\mathbf z_k - \mathbf h(\mathbf x^{(i)}); \mathbf 0, \mathbf R\big)

    (the residual wrapped where the model says so, ``model.diff_z``), and the filtering mean
    and covariance are the weighted moments. When the effective sample size
    :math:`1/\sum_i (w^{(i)})^2` falls below ``ess_threshold`` times ``N`` the particles are
    resampled (systematic resampling) and the weights reset. The moments converge to those of
    the exact posterior as ``N`` grows: a reference where the point-mass filter's grid would be
    too large (``nx > 1``). ``loglik`` is the log of the estimated likelihood
    :math:`p(\mathbf z_k|\mathbf z^{k-1})`; ``nis`` is not defined and is NaN.

    ``seed``: an int or a sequence of ints (the entropy of a ``numpy.random.SeedSequence``): every run
    draws from a fresh generator of it, so the same seed gives the same run. A ``numpy.random.Generator``
    is drawn from as it is and moves on: a second run then gives other numbers. ``params`` of the result
    holds the particle count (``param_name``), ``info["n_resampled"]`` the resampling steps per run.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.coordinated_turn()
    >>> traj = model.simulate(n_runs=5, n_steps=20, rng=0)
    >>> run = af.exact.BootstrapParticleFilter(model, n_particles=500, seed=0).run(traj.z)
    >>> run.mean.shape, run.cov.shape
    ((5, 20, 4), (5, 20, 4, 4))
    """

    #: what ``run(z).params`` holds (:class:`~adaptfilt.filters.Filter`)
    param_name = "n_particles"

    def __init__(self, model: StateSpaceModel, n_particles: int = 1000,
                 seed: int | Sequence[int] | np.random.Generator = 0, ess_threshold: float = 0.5):
        if int(n_particles) < 2:
            raise ValueError(f"n_particles must be at least 2, got {n_particles}")
        if not 0.0 <= ess_threshold <= 1.0:
            raise ValueError(f"ess_threshold must be in [0, 1], got {ess_threshold}")
        self.model, self.n_particles, self.seed, self.ess_threshold = model, int(n_particles), seed, float(ess_threshold)

    def __repr__(self) -> str:
        return (f"BootstrapParticleFilter(model={self.model.name!r}, n_particles={self.n_particles}, "
                f"ess_threshold={self.ess_threshold:g})")

    def run(self, z) -> FilterRun:
        """Filter ``z (M, T, nz)``; ``info["n_resampled"]`` counts the resampling steps per run."""
        model, N = self.model, self.n_particles
        z = np.asarray(z, dtype=float)
        if z.ndim == 2 and model.nz == 1:
            z = z[..., None]
        if z.ndim != 3 or z.shape[2] != model.nz:
            raise ValueError(f"z must have shape (M, T, {model.nz}), got {z.shape}")
        M, T, _ = z.shape
        rng = np.random.default_rng(self.seed)
        Lq, L0 = np.linalg.cholesky(model.Q), np.linalg.cholesky(model.P0)
        Rinv = np.linalg.inv(model.R)
        logdetR = np.linalg.slogdet(model.R)[1]
        x = model.m0 + rng.standard_normal((M, N, model.nx)) @ L0.T  # (M, N, nx)
        logw = np.full((M, N), -np.log(N))
        mean, cov, ll = np.empty((M, T, model.nx)), np.empty((M, T, model.nx, model.nx)), np.empty((M, T))
        n_res = np.zeros(M, dtype=int)
        for t in range(T):
            if t:
                x = model.f(x, t) + rng.standard_normal(x.shape) @ Lq.T
            r = model.diff_z(z[:, t, None, :], model.h(x, t + 1))  # (M, N, nz)
            loglik = -0.5 * (np.einsum("mni,ij,mnj->mn", r, Rinv, r) + logdetR + model.nz * np.log(2 * np.pi))
            a = logw + loglik
            amax = a.max(axis=1, keepdims=True)
            if not np.isfinite(amax).all():
                bad = np.flatnonzero(~np.isfinite(amax[:, 0]))
                raise ValueError(f"particle filter: no particle explains the measurement at step t={t} in runs "
                                 f"{bad[:10]}: use more particles")
            c = np.log(np.exp(a - amax).sum(axis=1)) + amax[:, 0]
            ll[:, t] = c
            logw = a - c[:, None]
            w = np.exp(logw)
            mean[:, t] = (w[:, None, :] @ x)[:, 0]
            d = x - mean[:, t, None, :]
            cov[:, t] = (d * w[..., None]).transpose(0, 2, 1) @ d
            ess = 1.0 / (w * w).sum(axis=1)
            res = np.flatnonzero(ess < self.ess_threshold * N)
            if res.size:
                u = (rng.random((res.size, 1)) + np.arange(N)) / N  # systematic: one uniform per run
                cdf = np.cumsum(w[res], axis=1)
                cdf[:, -1] = 1.0
                off = 2.0 * np.arange(res.size)[:, None]  # one sorted search for all runs: run i in [2i, 2i + 1]
                idx = np.searchsorted((cdf + off).ravel(), (u + off).ravel()).reshape(res.size, N)
                idx = np.minimum(idx - N * np.arange(res.size)[:, None], N - 1)
                x[res] = np.take_along_axis(x[res], idx[..., None], axis=1)
                logw[res] = -np.log(N)
                n_res[res] += 1
        return FilterRun(mean=mean, cov=cov, nis=np.full((M, T), np.nan), loglik=ll,
                         params=np.full((M, T), float(N)), info={"n_resampled": n_res})


@dataclass
class BayesFloor:
    """The point-mass filter's squared errors ``se (n, T)`` on the first ``n`` runs of an evaluation, and its
    ``grid`` (as results record it): :attr:`rmse` is the floor of the evaluation's time-averaged RMSE."""

    se: np.ndarray
    grid: str

    @property
    def runs(self) -> int:
        return int(self.se.shape[0])

    @property
    def rmse_t(self) -> np.ndarray:
        """``RMSE_k (T,)``."""
        return np.sqrt(self.se.mean(axis=0))

    @property
    def rmse(self) -> float:
        """The time average of :attr:`rmse_t`, as an evaluation's ``rmse``."""
        return float(self.rmse_t.mean())

    @property
    def run_rmse(self) -> np.ndarray:
        """Each run's own RMS error ``(n,)``."""
        return np.sqrt(self.se.mean(axis=1))

    def summary(self) -> dict:
        """``{"rmse", "runs", "grid"}``: what a study's results hold of its floor."""
        return {"rmse": self.rmse, "runs": self.runs, "grid": self.grid}


def bayes_floor(model: StateSpaceModel, runs, n: int, grid, chunk: int | None = None) -> BayesFloor:
    r"""The Bayes floor on the first ``n`` runs of an evaluation: the :class:`PointMassFilter` with ``model``
    on ``grid``, the MMSE estimate up to the grid's resolution, so that no filter's RMSE on these runs can
    be below it but by chance.

    ``runs``: the evaluation's :class:`~adaptfilt.runs.EvalRuns` (its :meth:`~adaptfilt.runs.EvalRuns.first`
    ``n`` runs: the runs the policies are scored on) or a :class:`~adaptfilt.models.Trajectory`; ``model``:
    the truth's model (the filter that knows the truth); ``grid``: an increasing, equally spaced array
    (:data:`UNGM_FLOOR_GRID`, :data:`UNGM_STUDY_FLOOR_GRID`); ``chunk``: runs filtered at a time
    (:meth:`PointMassFilter.run`, the same numbers as separate calls). Scalar models only (ValueError).

    Example
    -------
    >>> import adaptfilt as af
    >>> from adaptfilt.runs import EvalRuns
    >>> runs = EvalRuns(af.models.ungm(), n_runs=30, seed=0, n_steps=8)
    >>> floor = bayes_floor(af.models.ungm(), runs, 12, UNGM_FLOOR_GRID)
    >>> floor.runs, floor.rmse_t.shape, floor.grid
    (12, (8,), 'np.linspace(-45, 45, 901)')
    """
    traj = runs.first(n) if hasattr(runs, "first") else runs[: int(n)]
    pmf = PointMassFilter(model, grid=grid)
    mean = pmf.run(traj.z, chunk=chunk).mean
    g = pmf.grid
    return BayesFloor(se=metrics.squared_error(traj.x, mean), grid=f"np.linspace({g[0]:g}, {g[-1]:g}, {g.size})")
