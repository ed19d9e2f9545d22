r"""Chapter 3, estimation is myopic: the information-state loop (:func:`phi_brr`, :func:`decision_loop`
with :func:`posterior_mean`, :func:`posterior_median`, :func:`posterior_map`), the filter loop with a
per-step parameter (:func:`filter_loop`), how a deviation propagates (:func:`divergence`,
:func:`deviation_costs`) and myopic against discounted choices (:func:`myopic_vs_discounted`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt.course.bayes import gauss_pdf, point_estimates

__all__ = ["phi_brr", "DecisionLoop", "decision_loop", "posterior_mean", "posterior_median", "posterior_map",
           "filter_loop", "divergence", "plot_divergence", "deviation_costs", "MyopicComparison",
           "myopic_vs_discounted"]


# ======================================================================== chapter 3
def phi_brr(model, grid: np.ndarray, s: np.ndarray, z_next: np.ndarray, t: int) -> np.ndarray:
    r"""The information-state dynamics :math:`\mathbf s_{k+1} = \Phi_\mathrm{BRR}(\mathbf s_k, \mathbf z_{k+1})` (eq. (10))
    on a grid, batched over runs: ``s (N, M)`` at step ``t`` -> ``(N, M)`` at ``t + 1``.

    Chapman-Kolmogorov (3b) then Bayes (3a), as in
    :class:`~adaptfilt.exact.PointMassFilter`. Note the arguments: no estimate.
    """
    dx = grid[1] - grid[0]
    Q, R = float(model.Q[0, 0]), float(model.R[0, 0])
    transition = gauss_pdf(grid[:, None] - model.f(grid[:, None], t + 1).T, Q) * dx   # p(x_{k+1} | x_k) on the grid
    pred = transition @ s                                                           # (3b)
    post = gauss_pdf(z_next[None, :] - model.h(grid[:, None], t + 2), R) * pred        # (3a), unnormalised
    return post / (post.sum(axis=0) * dx)


@dataclass
class DecisionLoop:
    """What :func:`decision_loop` recorded: ``states (T, N, M)``, ``estimates (M, T)``, ``exp_loss (M, T)``."""

    states: np.ndarray
    estimates: np.ndarray
    exp_loss: np.ndarray


def _squared(x, x_hat):
    return (x - x_hat) ** 2


def decision_loop(model, grid: np.ndarray, estimator: Callable, z: np.ndarray, loss: Callable = _squared) -> DecisionLoop:
    r"""Run the information-state MDP of Section III on a grid.

    At every step the loop asks ``estimator(s_k, t) -> (M,)`` for the reported
    estimates and records the expected loss
    :math:`\bar L(\mathbf s_k,\hat x_k) = \int L(x,\hat x_k)\,\mathbf s_k(x)\,dx`
    (``loss(x, x_hat)``, default squared); the next state comes from
    :func:`phi_brr`, which never sees the estimate.
    """
    grid = np.asarray(grid, dtype=float)
    dx = grid[1] - grid[0]
    zz = np.asarray(z, dtype=float)[..., 0]                                 # (M, T), scalar measurements
    M, T = zz.shape
    prior = np.repeat(gauss_pdf(grid - model.m0[0], float(model.P0[0, 0]))[:, None], M, axis=1)
    post = gauss_pdf(zz[None, :, 0] - model.h(grid[:, None], 1), float(model.R[0, 0])) * prior
    s = post / (post.sum(axis=0) * dx)                                     # s_1: Bayes (3a) on the prior
    states, est, exp_loss = np.empty((T, grid.size, M)), np.empty((M, T)), np.empty((M, T))
    for t in range(T):                                                      # t = k - 1
        if t:
            s = phi_brr(model, grid, s, zz[:, t], t - 1)
        states[t], est[:, t] = s, estimator(s, t)
        exp_loss[:, t] = (loss(grid[:, None], est[None, :, t]) * s).sum(axis=0) * dx
    return DecisionLoop(states, est, exp_loss)


def posterior_mean(grid: np.ndarray) -> Callable:
    """Estimator for :func:`decision_loop`: the mean of ``s (N, M)``."""
    dx = grid[1] - grid[0]
    return lambda s, t: (grid[:, None] * s).sum(axis=0) * dx


def posterior_median(grid: np.ndarray) -> Callable:
    """Estimator for :func:`decision_loop`: the median of ``s (N, M)`` (first grid point with CDF >= 1/2)."""
    return lambda s, t: point_estimates(grid, s.T)["median"]


def posterior_map(grid: np.ndarray) -> Callable:
    """Estimator for :func:`decision_loop`: the grid maximum of ``s (N, M)``."""
    return lambda s, t: grid[s.argmax(axis=0)]


def filter_loop(filt, z: np.ndarray, kappa_per_step: np.ndarray, x_shift: np.ndarray | None = None):
    r"""Algorithm 1 written with the single-step API: :math:`\bar{\mathbf s}_{k+1} =
    \Phi_\mathrm{filter}(\bar{\mathbf s}_k, \mathbf z_k, \boldsymbol\theta_k)` with the
    update parameter ``kappa_per_step[t]`` (eq. (16)).

    ``x_shift (T,)`` (optional) is added to the filtering mean before the next
    prediction: a reported estimate that is fed back into the filter.
    Returns ``(mean (M, T, nx), cov (M, T, nx, nx))``.
    """
    M, T = z.shape[:2]
    model = filt.model
    x_pred, P_pred = np.tile(model.m0, (M, 1)), np.tile(model.P0, (M, 1, 1))
    mean, cov = np.empty((M, T, model.nx)), np.empty((M, T, model.nx, model.nx))
    for t in range(T):
        u = filt.update(x_pred, P_pred, z[:, t], t, param=kappa_per_step[t])     # theta_k enters here
        x_filt = u.x_filt + (0.0 if x_shift is None else x_shift[t])
        mean[:, t], cov[:, t] = x_filt, u.P_filt
        if t + 1 < T:
            p = filt.predict(x_filt, u.P_filt, t)
            x_pred, P_pred = p.x_pred, p.P_pred
    return mean, cov


def divergence(mean_a, cov_a, mean_b, cov_b, pos: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    r"""How far run ``a`` moved from reference ``b``, both relative, ``(M, T)`` each:

    the change of the (position) mean in the reference's standard deviations,
    :math:`\|\Delta\hat{\mathbf x}\|/\sqrt{\operatorname{tr}\mathbf P_b}`, and the relative
    change of the covariance trace, :math:`|\operatorname{tr}\mathbf P_a-\operatorname{tr}\mathbf P_b|/\operatorname{tr}\mathbf P_b`
    (traces over the ``pos`` block).
    """
    pos = list(pos)
    block = lambda c: np.trace(np.asarray(c)[..., pos, :][..., :, pos], axis1=-2, axis2=-1)
    tr_a, tr_b = block(cov_a), block(cov_b)
    dm = np.linalg.norm((np.asarray(mean_a) - np.asarray(mean_b))[..., pos], axis=-1)
    return dm / np.sqrt(tr_b), np.abs(tr_a - tr_b) / tr_b


def plot_divergence(results: Mapping[str, tuple[np.ndarray, np.ndarray]], t0: int, quantiles=(0.5, 0.9)):
    """One panel per model: quantiles over runs of the two :func:`divergence` measures after step ``t0``."""
    from adaptfilt import style

    fig, axes = style.figure(1, len(results), sharey=True, size=(7.5, 3.6))
    for ax, (name, (dm, dP)) in zip(np.atleast_1d(axes), results.items()):
        lag = np.arange(dm.shape[1] - t0)
        for q, ls in zip(quantiles, ("-", "--", ":")):
            nz = lambda a: np.where(a > 0, a, np.nan)  # exact zeros cannot be drawn on a log axis
            ax.semilogy(lag, nz(np.quantile(dm[:, t0:], q, axis=0)), color=style.OKABE_ITO[0], ls=ls,
                        label=f"mean, {q:.0%} quantile")
            ax.semilogy(lag, nz(np.quantile(dP[:, t0:], q, axis=0)), color=style.OKABE_ITO[1], ls=ls,
                        label=f"covariance, {q:.0%} quantile")
        ax.set(title=name, xlabel="steps after $k_0$", ylim=(1e-17, 1e2))
    np.atleast_1d(axes)[0].set_ylabel("relative change")
    np.atleast_1d(axes)[-1].legend(loc="lower left", fontsize="small")
    return fig


def deviation_costs(filt, z: np.ndarray, grid: Sequence[float], t0: int) -> np.ndarray:
    r"""NIS costs :math:`(\mathrm{NIS}_k - n_z)^2` ``(G, M, T)`` of the one-step deviations:
    the filter's default update parameter everywhere except ``grid[g]`` at step ``t0``."""
    M, T = z.shape[:2]
    out = []
    for value in grid:
        sched = np.full((M, T), filt.param)
        sched[:, t0] = value
        out.append((filt.run(z, params=sched).nis - filt.model.nz) ** 2)
    return np.array(out)


@dataclass
class MyopicComparison:
    """Per run: the grid index that minimises the immediate cost (``myopic``) and the
    discounted cost (``farsighted``), and the discounted costs ``(G, M)``."""

    myopic: np.ndarray
    farsighted: np.ndarray
    discounted: np.ndarray

    @property
    def differ(self) -> float:
        """Fraction of runs where the two choices differ."""
        return float(np.mean(self.myopic != self.farsighted))

    def mean_cost(self, which: str) -> float:
        """Mean over runs of the discounted cost of the ``"myopic"`` or ``"farsighted"`` choice."""
        idx = {"myopic": self.myopic, "farsighted": self.farsighted}[which]
        return float(self.discounted[idx, np.arange(idx.size)].mean())


def myopic_vs_discounted(costs: np.ndarray, t0: int, gamma: float) -> MyopicComparison:
    r"""Compare, per run, the parameter minimising the cost at ``t0`` alone with the one minimising
    :math:`\sum_{j\ge0}\gamma^j \bar L_{t_0+j}`; ``costs (G, M, T)`` from :func:`deviation_costs`.

    With ``gamma = 0`` the two criteria coincide (up to ties).
    """
    if not 0.0 <= gamma <= 1.0:
        raise ValueError(f"gamma must be in [0, 1], got {gamma}")
    T = costs.shape[-1]
    discounted = (costs[:, :, t0:] * gamma ** np.arange(T - t0)).sum(axis=-1)
    return MyopicComparison(costs[:, :, t0].argmin(axis=0), discounted.argmin(axis=0), discounted)
