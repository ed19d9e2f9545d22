r"""Chapter 1, the Bayesian recursion: one step of Bayes' rule on a grid (:func:`grid_bayes_step`,
shown in the chapter with :func:`~adaptfilt.course.common.show_source`), the filtering densities of
UNGM (:func:`filtering_densities`), its sign ambiguity (:func:`sign_ambiguity`,
:func:`ambiguous_mask`, :func:`ambiguous_cases`), point estimates and their expected loss
(:func:`point_estimates`, :func:`expected_loss`), and their figures.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from adaptfilt.course.common import figure_axes

__all__ = ["BayesStep", "grid_bayes_step", "filtering_densities", "SignAmbiguity", "sign_ambiguity",
           "ambiguous_mask", "ambiguous_cases", "point_estimates", "ExpectedLoss", "expected_loss",
           "plot_ungm_roots", "plot_posteriors", "plot_bayes_step", "plot_expected_loss"]


# ======================================================================== chapter 1
@dataclass
class BayesStep:
    """One step of the Bayesian recursion on a grid: densities ``(N,)``."""

    predictive: np.ndarray  # p(x_k | z^{k-1}), eq. (3b)
    likelihood: np.ndarray  # p(z_k | x_k)
    posterior: np.ndarray  # p(x_k | z^k), eq. (3a)


def gauss_pdf(r, var: float):
    return np.exp(-0.5 * r * r / var) / np.sqrt(2 * np.pi * var)


def grid_bayes_step(model, grid: np.ndarray, prev: np.ndarray, z: float, t: int) -> BayesStep:
    r"""One step of eq. (3) for a scalar model on an equally spaced grid.

    .. math::
        p(x_k|z^{k-1}) = \sum_j \mathcal N(x_k; f(x^{(j)}), Q)\, p(x^{(j)}|z^{k-1}_{k-1})\,\Delta \quad (3b),\qquad
        p(x_k|z^k) \propto \mathcal N(z_k; h(x_k), R)\, p(x_k|z^{k-1}) \quad (3a)

    ``prev (N,)`` is the filtering density at step ``t - 1`` (array index;
    the paper's ``k = t + 1``), ``z`` the measurement at ``t``.

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model, grid = af.models.ungm(), np.linspace(-45, 45, 901)
    >>> prior = np.exp(-0.5 * grid**2 / 5) / np.sqrt(2 * np.pi * 5)
    >>> step = grid_bayes_step(model, grid, prior, z=1.0, t=1)
    >>> round(float(step.posterior.sum() * (grid[1] - grid[0])), 12)
    1.0
    """
    grid = np.asarray(grid, dtype=float)
    dx = grid[1] - grid[0]
    Q, R = float(model.Q[0, 0]), float(model.R[0, 0])
    transition = gauss_pdf(grid[:, None] - model.f(grid[:, None], t)[:, 0][None, :], Q)  # p(x_k = x_i | x_{k-1} = x_j)
    predictive = transition @ prev * dx                                                  # (3b)
    likelihood = gauss_pdf(z - model.h(grid[:, None], t + 1)[:, 0], R)                      # p(z_k | x_k)
    posterior = likelihood * predictive
    return BayesStep(predictive, likelihood, posterior / (posterior.sum() * dx))          # (3a)


def filtering_densities(pmf, z: np.ndarray) -> np.ndarray:
    """Filtering densities ``p(x_k | z^k)`` of a :class:`~adaptfilt.exact.PointMassFilter`
    at every step, ``(M, T, N)`` (memory: ``8 M T N`` bytes)."""
    z = np.asarray(z, dtype=float)
    T = z.shape[1]
    run = pmf.run(z, keep_density_at=tuple(range(T)))
    return np.stack([run.info["density"][t] for t in range(T)], axis=1)


@dataclass
class SignAmbiguity:
    """``p_neg = P(x_k < 0 | z^k)`` and ``abs_mean = E[|x_k| | z^k]``, ``(M, T)``."""

    p_neg: np.ndarray
    abs_mean: np.ndarray


def sign_ambiguity(grid: np.ndarray, dens: np.ndarray) -> SignAmbiguity:
    """Where the sign of a scalar state is uncertain: ``P(x < 0)`` and ``E|x|`` of densities ``(..., N)``."""
    grid = np.asarray(grid, dtype=float)
    dx = grid[1] - grid[0]
    return SignAmbiguity(p_neg=dens[..., grid < 0].sum(axis=-1) * dx, abs_mean=(np.abs(grid) * dens).sum(axis=-1) * dx)


def ambiguous_mask(amb: SignAmbiguity, p_range: tuple[float, float] = (0.2, 0.8),
                   min_abs_mean: float = 4.0) -> np.ndarray:
    """``(M, T)``: both signs at least ``p_range[0]`` likely and ``E|x| > min_abs_mean``
    (two well-separated peaks). ``t = 0`` is always False: there the symmetric prior
    makes every run trivially ambiguous."""
    lo, hi = p_range
    mask = (amb.p_neg > lo) & (amb.p_neg < hi) & (amb.abs_mean > min_abs_mean)
    mask[:, 0] = False
    return mask


def ambiguous_cases(amb: SignAmbiguity, n: int = 3, p_range: tuple[float, float] = (0.2, 0.8),
                    min_abs_mean: float = 4.0) -> list[tuple[int, int]]:
    """The ``n`` (run, t) pairs of :func:`ambiguous_mask` with the largest ``E|x|``, most separated first."""
    mask = ambiguous_mask(amb, p_range, min_abs_mean)
    cases = [(int(r), int(t)) for r, t in zip(*np.nonzero(mask))]
    return sorted(cases, key=lambda rt: -amb.abs_mean[rt])[:n]


def point_estimates(grid: np.ndarray, dens: np.ndarray) -> dict[str, np.ndarray]:
    """Posterior mean, median and maximum (MAP) of grid densities ``(..., N)``, each ``(...)``."""
    grid = np.asarray(grid, dtype=float)
    dx = grid[1] - grid[0]
    cdf = np.cumsum(dens, axis=-1) * dx
    median = grid[np.minimum((cdf < 0.5).sum(axis=-1), grid.size - 1)]
    return {"mean": (grid * dens).sum(axis=-1) * dx, "median": median, "MAP": grid[dens.argmax(axis=-1)]}


@dataclass
class ExpectedLoss:
    """``loss[i] = E[(x - candidates[i])^2 | z^k]`` and the posterior mean and MAP."""

    candidates: np.ndarray
    loss: np.ndarray
    mean: float
    map: float

    @property
    def argmin(self) -> float:
        return float(self.candidates[self.loss.argmin()])

    def at(self, x_hat: float) -> float:
        """Expected loss at ``x_hat`` (linear interpolation between candidates)."""
        return float(np.interp(x_hat, self.candidates, self.loss))


def expected_loss(grid: np.ndarray, post: np.ndarray, candidates: np.ndarray) -> ExpectedLoss:
    r"""Expected squared loss :math:`\int (x-\hat x)^2 p(x|z^k)\,dx` of each candidate
    estimate :math:`\hat x`, for a grid density ``post (N,)``.

    It equals :math:`\mathrm{Var}[x|z^k] + (\hat x - \mathrm{E}[x|z^k])^2`: a parabola
    whose minimum is the posterior mean.
    """
    grid, cand = np.asarray(grid, dtype=float), np.asarray(candidates, dtype=float)
    dx = grid[1] - grid[0]
    loss = ((grid[None, :] - cand[:, None]) ** 2 * post[None, :]).sum(axis=1) * dx
    return ExpectedLoss(cand, loss, float((grid * post).sum() * dx), float(grid[post.argmax()]))


def plot_ungm_roots(traj, run: int, ax=None):
    """UNGM: the true state of one run with the two states ``±sqrt(20 z_k)`` its measurement allows."""
    fig, ax = figure_axes(ax)
    x, z = traj.x[run, :, 0], traj.z[run, :, 0]
    k = np.arange(1, x.size + 1)
    root = np.sqrt(20 * np.clip(z, 0, None))
    ax.plot(k, x, "k-", lw=1.2, label="true state $x_k$")
    ax.plot(k, root, "o", ms=3, label=r"$+\sqrt{20 z_k}$")
    ax.plot(k, -root, "o", ms=3, label=r"$-\sqrt{20 z_k}$")
    ax.set(xlabel="time step $k$", ylabel="state $x_k$", ylim=(-24, 31),
           title=f"UNGM run {run}: the measurement fixes $|x_k|$, not its sign")
    ax.legend(loc="upper center", ncol=3)
    return fig


def plot_posteriors(grid: np.ndarray, dens: np.ndarray, x: np.ndarray, cases: Sequence[tuple[int, int]],
                    xlim: tuple[float, float] = (-15, 15)):
    """Small multiples of the exact posterior at the given (run, t), with the truth and the posterior mean."""
    from adaptfilt import style

    fig, axes = style.figure(1, len(cases), sharey=False, title="UNGM: the exact posterior is bimodal where the sign is ambiguous")
    mean = point_estimates(grid, dens[[r for r, _ in cases], [t for _, t in cases]])["mean"]
    for ax, (r, t), m in zip(np.atleast_1d(axes), cases, mean):
        ax.plot(grid, dens[r, t], color=style.OKABE_ITO[0])
        ax.axvline(x[r, t, 0], color="k", ls="--", lw=1, label="true $x_k$")
        ax.axvline(m, color=style.OKABE_ITO[3], lw=1.2, label="posterior mean")
        ax.set(xlim=xlim, xlabel="$x_k$", title=f"run {r}, k = {t + 1}")
    np.atleast_1d(axes)[0].set_ylabel("$p(x_k|z^k)$")
    # one legend for the row, below the panels: inside any panel it would cover a peak or a line
    fig.legend(*np.atleast_1d(axes)[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, frameon=False)
    return fig


def plot_bayes_step(grid: np.ndarray, step: BayesStep, title: str = "", ax=None, xlim=(-25, 25)):
    """Predictive density, (scaled) likelihood and posterior of one :class:`BayesStep`."""
    fig, ax = figure_axes(ax)
    ax.plot(grid, step.predictive, label=r"predictive $p(x_k|z^{k-1})$")
    ax.plot(grid, step.likelihood / step.likelihood.max() * step.predictive.max(), "--",
            label=r"likelihood $p(z_k|x_k)$ (scaled)")
    ax.plot(grid, step.posterior, label=r"posterior $p(x_k|z^k)$")
    ax.set(xlim=xlim, xlabel="$x_k$", ylabel="density", title=title)
    ax.legend()
    return fig


def plot_expected_loss(el: ExpectedLoss, title: str = "", ax=None):
    """The expected squared loss of each candidate estimate, with the posterior mean and MAP marked."""
    from adaptfilt.style import OKABE_ITO

    fig, ax = figure_axes(ax)
    ax.plot(el.candidates, el.loss, color="k", label=r"$\int (x-\hat{x})^2 p(x|z^k)\,dx$")
    ax.axvline(el.mean, color=OKABE_ITO[3], label=f"posterior mean {el.mean:.2f}")
    ax.axvline(el.map, color=OKABE_ITO[2], ls="--", label=f"MAP {el.map:.2f}")
    ax.set(xlabel=r"candidate estimate $\hat{x}_k$", ylabel="expected squared error", title=title)
    ax.legend()
    return fig
