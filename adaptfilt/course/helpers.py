r"""The plumbing of the course notebooks, so that a chapter reads as prose with short calls.

Where the code *is* the lesson (one step of Bayes' rule on a grid, the
information-state loop whose operator has no estimate argument, the filter loop
with a per-step parameter), a chapter shows it with :func:`show_source`; the
rest (bookkeeping, bootstrap bands, figures) lives here, documented and tested
(``tests/test_course.py``). Figures use :mod:`adaptfilt.style`.

========================================  =========================================================
chapter                                   helpers
========================================  =========================================================
all                                       :func:`show_source`, :func:`score`, :func:`score_table`,
                                          :func:`paired_rmse_difference`
1 The Bayesian recursion                  :func:`grid_bayes_step`, :func:`filtering_densities`,
                                          :func:`sign_ambiguity`, :func:`ambiguous_mask`,
                                          :func:`ambiguous_cases`,
                                          :func:`point_estimates`, :func:`expected_loss`
2 Gaussian-assumed filters                :func:`unscented_moments`, :func:`unscented_pzz`,
                                          :func:`plot_unscented` (widget :func:`show_unscented`),
                                          :func:`gauss_hermite_moments`, :func:`rule_errors`,
                                          :func:`plot_sif_draws` (widget :func:`show_sif_draws`),
                                          :func:`line_of_sight_errors`
3 Estimation is myopic                    :func:`phi_brr`, :func:`decision_loop`, :func:`filter_loop`,
                                          :func:`divergence`, :func:`deviation_costs`,
                                          :func:`myopic_vs_discounted`
4 Parameter adaptation as an MDP          :func:`innovation_spread`, :func:`kappa_sweep`,
                                          :func:`results_lines`, :func:`cost_samples`,
                                          :func:`cost_summary`
========================================  =========================================================

Arrays follow the library's public layout: runs first, ``(M, T, ...)``; a
grid density is ``(N,)`` for one run and ``(M, T, N)`` for all of them.
"""
from __future__ import annotations

import inspect
import textwrap
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from adaptfilt import metrics

__all__ = [
    "show_source", "Score", "score", "score_table", "paired_rmse_difference", "chi2_median",
    # chapter 1
    "BayesStep", "grid_bayes_step", "filtering_densities", "SignAmbiguity", "sign_ambiguity", "ambiguous_mask", "ambiguous_cases",
    "point_estimates", "ExpectedLoss", "expected_loss",
    "plot_ungm_roots", "plot_posteriors", "plot_bayes_step", "plot_expected_loss", "plot_rmse_k",
    # chapter 2
    "ungm_h", "bearing", "unscented_moments", "unscented_pzz", "plot_pzz_vs_kappa", "plot_unscented",
    "show_unscented", "gauss_hermite_moments", "RuleErrors", "rule_errors", "plot_rule_errors", "plot_sif_draws",
    "show_sif_draws", "plot_anees_k", "plot_per_run_rmse", "line_of_sight_errors", "plot_line_of_sight_errors",
    # chapter 3
    "phi_brr", "DecisionLoop", "decision_loop", "posterior_mean", "posterior_median", "posterior_map",
    "filter_loop", "divergence", "plot_divergence", "deviation_costs", "MyopicComparison", "myopic_vs_discounted",
    # chapter 4
    "innovation_spread", "kappa_sweep", "plot_sweep", "results_lines", "cost_samples", "cost_summary",
    "plot_cost_distribution",
]


def show_source(obj, lines: tuple[int, int] | None = None):
    """Display the source of a library object in a notebook, highlighted.

    The course shows library code instead of copying it, so that what the
    reader sees is what runs. ``lines=(a, b)`` shows a slice of the source.
    """
    from IPython.display import Markdown

    src = inspect.getsource(obj)
    if lines is not None:
        src = "\n".join(src.splitlines()[lines[0]:lines[1]])
    return Markdown(f"```python\n{textwrap.dedent(src)}\n```")


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _ax(ax, **figure_kw):
    """``ax`` itself, or a new single-panel course figure."""
    if ax is not None:
        return ax.figure, ax
    from adaptfilt import style

    return style.figure(**figure_kw)


# ======================================================================== scores
@dataclass
class Score:
    """Accuracy and consistency of one filter on ``M`` runs of ``T`` steps.

    ``rmse_k (T,)`` with its pointwise bootstrap band ``rmse_band (2, T)``;
    ``rmse`` the time average of ``RMSE_k`` with bootstrap CI ``rmse_ci``;
    ``anees_k (T,)`` and its time average ``anees``; ``nees (M, T)``;
    ``run_rmse (M,)`` the RMS error of each run over time.
    """

    rmse_k: np.ndarray
    rmse_band: np.ndarray
    rmse: float
    rmse_ci: tuple[float, float]
    anees_k: np.ndarray
    anees: float
    nees: np.ndarray
    run_rmse: np.ndarray

    @property
    def median_run_rmse(self) -> float:
        """Median over runs of the per-run RMS error."""
        return float(np.median(self.run_rmse))

    @property
    def median_nees(self) -> float:
        """Median of NEES over all (run, step) pairs (for a consistent filter: the median of chi2(nx))."""
        return float(np.median(self.nees))


def score(x: np.ndarray, run, counts: np.ndarray, level: float = 0.95) -> Score:
    r"""Score a filter run against the true states.

    .. math::
        \mathrm{RMSE}_k = \sqrt{\tfrac1M\textstyle\sum_\ell \tilde x_{k|k}(\ell)^T\tilde x_{k|k}(\ell)},\qquad
        \mathrm{ANEES}_k = \tfrac1M\textstyle\sum_\ell \tilde x_{k|k}(\ell)^T P_{k|k}(\ell)^{-1}\tilde x_{k|k}(\ell)

    ``run`` has ``mean (M, T, nx)`` and ``cov (M, T, nx, nx)`` (a
    :class:`~adaptfilt.gaf.FilterRun`); ``counts`` are bootstrap resampling
    counts (:func:`adaptfilt.metrics.bootstrap_counts`): reuse them across
    filters for paired intervals. A covariance that a clipping filter stored
    indefinite is scored through a plain solve (``on_indefinite="solve"``).

    Example
    -------
    >>> import numpy as np, adaptfilt as af
    >>> model = af.models.ungm()
    >>> traj = model.simulate(n_runs=50, n_steps=20, rng=0)
    >>> s = score(traj.x, af.UKF(model).run(traj.z), af.metrics.bootstrap_counts(50, 200))
    >>> s.rmse_k.shape, s.rmse_ci[0] <= s.rmse <= s.rmse_ci[1]
    ((20,), True)
    """
    se = metrics.squared_error(x, run.mean)
    M = se.shape[0]
    counts = np.asarray(counts, dtype=float)
    if counts.ndim != 2 or counts.shape[1] != M:
        raise ValueError(f"counts must have shape (n_boot, M = {M}), got {counts.shape}")
    boot_k = np.sqrt(counts @ se / M)  # (n_boot, T)
    a = (1.0 - level) / 2.0
    nees = metrics.nees(x, run.mean, run.cov, on_indefinite="solve")
    anees_k = nees.mean(axis=0)
    return Score(
        rmse_k=np.sqrt(se.mean(axis=0)), rmse_band=np.quantile(boot_k, [a, 1.0 - a], axis=0),
        rmse=metrics.rmse_time_average(se), rmse_ci=metrics.percentile_ci(boot_k.mean(axis=1), level),
        anees_k=anees_k, anees=float(anees_k.mean()), nees=nees, run_rmse=np.sqrt(se.mean(axis=1)),
    )


def score_table(scores: Mapping[str, Score]) -> str:
    """A text table of scores: time-averaged RMSE with CI, median per-run RMSE, ANEES, median NEES."""
    from adaptfilt.style import policy_label

    names = {n: policy_label(n) for n in scores}
    w = max(24, *(len(v) for v in names.values()))
    rows = [f"{'filter':<{w}} {'RMSE':>6} {'95% CI':>15} {'median run RMSE':>16} {'ANEES':>9} {'median NEES':>12}"]
    for n, s in scores.items():
        rows.append(f"{names[n]:<{w}} {s.rmse:6.2f} [{s.rmse_ci[0]:6.2f}, {s.rmse_ci[1]:6.2f}] "
                    f"{s.median_run_rmse:16.2f} {s.anees:9.3g} {s.median_nees:12.2f}")
    return "\n".join(rows)


def paired_rmse_difference(x: np.ndarray, run_a, run_b, counts: np.ndarray,
                           level: float = 0.95) -> tuple[float, float, float]:
    """Time-averaged RMSE of ``run_a`` minus that of ``run_b`` on the same runs, with a
    *paired* bootstrap interval (both resampled with the same ``counts``): ``(diff, lo, hi)``."""
    se_a, se_b = metrics.squared_error(x, run_a.mean), metrics.squared_error(x, run_b.mean)
    boot = metrics.bootstrap_rmse(se_a, counts) - metrics.bootstrap_rmse(se_b, counts)
    lo, hi = metrics.percentile_ci(boot, level)
    return metrics.rmse_time_average(se_a) - metrics.rmse_time_average(se_b), lo, hi


def chi2_median(dof: int) -> float:
    """Median of the chi-square distribution with ``dof`` degrees of freedom
    (0.455 for ``dof = 1``): the median NEES of a consistent filter with ``nx = dof``."""
    from scipy import stats

    if dof < 1:
        raise ValueError(f"dof must be a positive integer, got {dof}")
    return float(stats.chi2.median(dof))


def plot_rmse_k(scores: Mapping[str, Score], ax=None, title: str | None = None, colors: Sequence | None = None):
    """``RMSE_k`` of each score over time with its 95 % bootstrap band; returns the figure."""
    from adaptfilt.style import policy_label

    fig, ax = _ax(ax)
    for i, (n, s) in enumerate(scores.items()):
        c = None if colors is None else colors[i]
        k = np.arange(1, s.rmse_k.size + 1)
        line, = ax.plot(k, s.rmse_k, color=c, label=policy_label(n))
        ax.fill_between(k, *s.rmse_band, color=line.get_color(), alpha=0.2, lw=0)
    ax.set(xlabel="time step $k$", ylabel=r"RMSE$_k$", title=title or "RMSE over time (95 % bootstrap bands)")
    ax.set_ylim(0, None)
    ax.legend()
    return fig


# ======================================================================== chapter 1
@dataclass
class BayesStep:
    """One step of the Bayesian recursion on a grid: densities ``(N,)``."""

    predictive: np.ndarray  # p(x_k | z^{k-1}), eq. (3b)
    likelihood: np.ndarray  # p(z_k | x_k)
    posterior: np.ndarray  # p(x_k | z^k), eq. (3a)


def _gauss(r, var: float):
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
    transition = _gauss(grid[:, None] - model.f(grid[:, None], t)[:, 0][None, :], Q)  # p(x_k = x_i | x_{k-1} = x_j)
    predictive = transition @ prev * dx                                                  # (3b)
    likelihood = _gauss(z - model.h(grid[:, None], t + 1)[:, 0], R)                      # p(z_k | x_k)
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
    fig, ax = _ax(ax)
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
    np.atleast_1d(axes)[-1].legend(loc="upper left")
    return fig


def plot_bayes_step(grid: np.ndarray, step: BayesStep, title: str = "", ax=None, xlim=(-25, 25)):
    """Predictive density, (scaled) likelihood and posterior of one :class:`BayesStep`."""
    fig, ax = _ax(ax)
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

    fig, ax = _ax(ax)
    ax.plot(el.candidates, el.loss, color="k", label=r"$\int (x-\hat{x})^2 p(x|z^k)\,dx$")
    ax.axvline(el.mean, color=OKABE_ITO[3], label=f"posterior mean {el.mean:.2f}")
    ax.axvline(el.map, color=OKABE_ITO[2], ls="--", label=f"MAP {el.map:.2f}")
    ax.set(xlabel=r"candidate estimate $\hat{x}_k$", ylabel="expected squared error", title=title)
    ax.legend()
    return fig


# ======================================================================== chapter 2
def ungm_h(X: np.ndarray) -> np.ndarray:
    """UNGM's measurement function ``x^2 / 20`` (any layout)."""
    return X ** 2 / 20


def bearing(X: np.ndarray) -> np.ndarray:
    """``atan2(x_2, x_1)`` in the rules' run-last layout: ``X (2, points, runs) -> (1, points, runs)``."""
    return np.arctan2(X[1:2], X[0:1])


def unscented_moments(h: Callable, kappas, m, P):
    """Unscented moments of ``h(x)``, ``x ~ N(m, P)``, for every ``kappa`` in one batched call.

    ``m (n,)``, ``P (n, n)``; returns :class:`~adaptfilt.rules.Moments` with
    the run axis (last) indexing ``kappas``.
    """
    from adaptfilt.rules import UnscentedRule

    kappas = np.atleast_1d(np.asarray(kappas, dtype=float))
    m, P = np.atleast_1d(np.asarray(m, dtype=float)), np.atleast_2d(np.asarray(P, dtype=float))
    G = kappas.size
    return UnscentedRule().moments(h, np.repeat(m[:, None], G, axis=1), np.repeat(P[:, :, None], G, axis=2), kappas)


def unscented_pzz(kappas, m: float, P: float, R: float = 0.1, h: Callable = ungm_h) -> np.ndarray:
    r"""``P^zz`` of the unscented rule for a scalar ``x ~ N(m, P)`` and each ``kappa``.

    For UNGM's ``h = x^2/20`` it is :math:`(4m^2P + \kappa P^2)/400 + R`
    (the exact value has :math:`2P^2` in place of :math:`\kappa P^2`).
    """
    return unscented_moments(h, kappas, [m], [[P]]).cov[0, 0] + R


def _pzz_exact_ungm(m: float, P: float, R: float) -> float:
    return (4 * m ** 2 * P + 2 * P ** 2) / 400 + R


def plot_pzz_vs_kappa(kappas, cases: Sequence[tuple[float, float]], R: float = 0.1, ax=None):
    """UNGM: ``P^zz`` of the unscented rule against ``kappa`` for each ``(m, P)``, with the exact value."""
    from adaptfilt.style import param_label

    fig, ax = _ax(ax)
    for m, P in cases:
        line, = ax.plot(kappas, unscented_pzz(kappas, m, P, R), label=f"UT, m = {m:g}, P = {P:g}")
        ax.axhline(_pzz_exact_ungm(m, P, R), color=line.get_color(), ls="--", lw=1, label=f"exact, m = {m:g}, P = {P:g}")
    ax.axvline(2, color="k", ls=":", lw=1)
    ax.annotate(r"$n+\kappa=3$", (2, 0), xytext=(4, 4), textcoords="offset points")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set(xlabel=param_label("kappa"), ylabel=r"$P^{zz}$",
           title=r"UNGM measurement $x^2/20$: $P^{zz}$ of the unscented rule vs " + param_label("kappa"))
    ax.legend(ncol=2)
    return fig


def plot_unscented(kappa: float, ax=None, m: float = 5.0, P: float = 4.0, R: float = 0.1):
    r"""The unscented rule on UNGM's measurement for one ``kappa``: the sigma points of
    ``x ~ N(m, P)`` drawn as stems whose height is their weight, over the (scaled)
    density of ``x``, with ``P^zz`` of the rule and the exact value.

    Points :math:`m` and :math:`m\pm\sqrt{(1+\kappa)P}`, weights
    :math:`\kappa/(1+\kappa)` and :math:`1/(2(1+\kappa))`; a negative centre
    weight (``kappa < 0``) is drawn below zero. Returns the figure.
    """
    from adaptfilt.style import OKABE_ITO, param_label

    if not kappa > -1:
        raise ValueError(f"kappa must satisfy 1 + kappa > 0 for a scalar state, got {kappa}")
    fig, ax = _ax(ax)
    s = np.sqrt((1 + kappa) * P)
    pts, w = np.array([m - s, m, m + s]), np.array([0.5, kappa, 0.5]) / (1 + kappa)
    xs = np.linspace(m - 4.5 * np.sqrt(P), m + 4.5 * np.sqrt(P), 300)
    ax.fill_between(xs, np.exp(-0.5 * (xs - m) ** 2 / P), color="0.85", lw=0, label=r"$\mathcal{N}(m, P)$ (scaled)")
    ax.vlines(pts, 0, w, color=OKABE_ITO[0], lw=2)
    ax.plot(pts, w, "o", color=OKABE_ITO[0], label="sigma points (height: weight)")
    ax.axhline(0, color="k", lw=0.6)
    ax.margins(y=0.08)  # autoscaled: small multiples with a shared y axis then show every weight
    pzz = float(unscented_pzz([kappa], m, P, R)[0])
    ax.set(xlabel="$x$", ylabel="weight", xlim=(min(xs[0], pts[0]) - 1, max(xs[-1], pts[-1]) + 1),
           title=f"{param_label('kappa', round(float(kappa), 3))}\n$P^{{zz}}$ {pzz:.3g} (exact {_pzz_exact_ungm(m, P, R):.3g})")
    return fig


def show_unscented(kappa: float = 2.0, m: float = 5.0, P: float = 4.0) -> None:
    """Widget callback (``ipywidgets.interact``): draw :func:`plot_unscented` and show it."""
    plot_unscented(kappa, m=m, P=P)
    _plt().show()


def gauss_hermite_moments(g: Callable, m, P, order: int = 60) -> tuple[float, float]:
    r"""Mean and variance of a scalar ``g(x)``, ``x ~ N(m, P)`` in ``n`` dimensions, by the
    tensor-product Gauss-Hermite rule with ``order`` nodes per axis (``order ** n``
    evaluations): the reference for the stochastic rules.

    ``g`` takes the rules' run-last layout ``(n, points, runs)`` and returns ``(1, points, runs)``.

    Example
    -------
    >>> m, v = gauss_hermite_moments(lambda X: X[0:1] ** 2, [1.0], [[2.0]], order=10)
    >>> round(m, 10), round(v, 10)                     # E[x^2] = m^2 + P, Var[x^2] = 4 m^2 P + 2 P^2
    (3.0, 16.0)
    """
    from numpy.polynomial.hermite_e import hermegauss

    m, P = np.atleast_1d(np.asarray(m, dtype=float)), np.atleast_2d(np.asarray(P, dtype=float))
    n = m.size
    nodes, w = hermegauss(order)
    w = w / w.sum()
    U = np.stack(np.meshgrid(*[nodes] * n, indexing="ij")).reshape(n, -1)
    W = np.prod(np.stack(np.meshgrid(*[w] * n, indexing="ij")).reshape(n, -1), axis=0)
    X = m[:, None] + np.linalg.cholesky(P) @ U
    G = np.asarray(g(X[:, :, None]))[0, :, 0]
    mean = float(W @ G)
    return mean, float(W @ (G - mean) ** 2)


@dataclass
class RuleErrors:
    """RMS errors (over repetitions) of a rule's ``E[g]`` and ``Var[g]`` against a reference, one per setting."""

    mean: np.ndarray
    var: np.ndarray


def rule_errors(rule, g: Callable, m, P, params, reference: tuple[float, float], n_batch: int = 1,
                seed: int = 0) -> RuleErrors:
    """Errors of a moment rule's mean and variance of scalar ``g(x)``, ``x ~ N(m, P)``.

    For each parameter value the rule runs on ``n_batch`` identical "runs" (a
    stochastic rule then gives ``n_batch`` independent estimates, drawn from
    ``default_rng(seed)``); the errors are root-mean-square over them.
    """
    m, P = np.atleast_1d(np.asarray(m, dtype=float)), np.atleast_2d(np.asarray(P, dtype=float))
    mb, Pb = np.repeat(m[:, None], n_batch, axis=1), np.repeat(P[:, :, None], n_batch, axis=2)
    err_m, err_v = [], []
    for p in np.atleast_1d(params):
        rng = np.random.default_rng(seed) if rule.stochastic else None
        mo = rule.moments(g, mb, Pb, p, rng=rng)
        err_m.append(np.sqrt(np.mean((mo.mean[0] - reference[0]) ** 2)))
        err_v.append(np.sqrt(np.mean((mo.cov[0, 0] - reference[1]) ** 2)))
    return RuleErrors(np.array(err_m), np.array(err_v))


def plot_rule_errors(n_iters, sir: RuleErrors, ut: RuleErrors, ax=None):
    """Log-log errors of the stochastic rule against iterations, the ``N^-1/2`` slope and the UT's bias."""
    from adaptfilt.style import OKABE_ITO

    fig, ax = _ax(ax)
    n_iters = np.asarray(n_iters, dtype=float)
    ax.loglog(n_iters, sir.mean, "o-", color=OKABE_ITO[0], label=r"SIR: RMS error of $\mathrm{E}[g]$")
    ax.loglog(n_iters, sir.var, "s-", color=OKABE_ITO[1], label=r"SIR: RMS error of $\mathrm{Var}[g]$")
    ax.loglog(n_iters, sir.mean[0] * n_iters ** -0.5, "k:", label=r"slope $-1/2$")
    ax.axhline(ut.mean[0], color=OKABE_ITO[0], ls="--", lw=1, label=r"UT ($\kappa = 1$): error of $\mathrm{E}[g]$")
    ax.axhline(ut.var[0], color=OKABE_ITO[1], ls="--", lw=1, label=r"UT ($\kappa = 1$): error of $\mathrm{Var}[g]$")
    ax.set(xlabel=r"iterations $N_\mathrm{it}$", ylabel="error vs Gauss-Hermite",
           title="Stochastic integration: error vs iterations (bearing function)")
    ax.legend(ncol=2, fontsize="small")
    return fig


_BEARING_M = (20.0, 5.0)
_BEARING_P = ((25.0, 5.0), (5.0, 16.0))


def plot_sif_draws(n_iter: int, ax=None, m=_BEARING_M, P=_BEARING_P, g: Callable = bearing, n_batch: int = 2000,
                   seed: int = 0, legend: bool = True, half_width: float = 0.025):
    """Histogram of ``n_batch`` independent stochastic-integration estimates of ``E[g(x)]``
    with ``n_iter`` iterations each, against the Gauss-Hermite value (black) and the unscented
    rule's (dashed, ``kappa = 3 - n``), on a fixed axis ``reference +- half_width``.
    The spread (its RMS error is in the title) shrinks like ``n_iter ** -0.5``; returns the figure.
    """
    from adaptfilt.rules import StochasticIntegrationRule, UnscentedRule
    from adaptfilt.style import OKABE_ITO

    if int(n_iter) < 1:
        raise ValueError(f"n_iter must be a positive integer, got {n_iter}")
    fig, ax = _ax(ax)
    m, P = np.asarray(m, dtype=float), np.asarray(P, dtype=float)
    ref = gauss_hermite_moments(g, m, P)[0]
    mb, Pb = np.repeat(m[:, None], n_batch, axis=1), np.repeat(P[:, :, None], n_batch, axis=2)
    est = StochasticIntegrationRule().moments(g, mb, Pb, int(n_iter), rng=np.random.default_rng(seed)).mean[0]
    ut = float(UnscentedRule().moments(g, m[:, None], P[:, :, None], 3.0 - m.size).mean[0, 0])
    half = float(half_width)  # a fixed axis: the narrowing is the lesson
    ax.hist(est, bins=np.linspace(ref - half, ref + half, 51), color=OKABE_ITO[0], alpha=0.8)
    ax.axvline(ref, color="k", lw=1.2, label="Gauss-Hermite")
    ax.axvline(ut, color=OKABE_ITO[3], ls="--", lw=1.2, label="unscented")
    ax.set(xlabel=r"estimate of $\mathrm{E}[g(x)]$", ylabel="repetitions", xlim=(ref - half, ref + half),
           title=f"$N_\\mathrm{{it}}$ = {int(n_iter)}\nRMS error {np.sqrt(np.mean((est - ref) ** 2)):.2g}")
    if legend:
        ax.legend(loc="upper right", fontsize="small")
    return fig


def show_sif_draws(n_iter: int = 8, m=_BEARING_M, P=_BEARING_P) -> None:
    """Widget callback (``ipywidgets.interact``): draw :func:`plot_sif_draws` and show it."""
    plot_sif_draws(n_iter, m=m, P=P)
    _plt().show()


def plot_anees_k(scores: Mapping[str, Score], nx: int, median_of: Mapping[str, Score] | None = None,
                 level: float = 0.95, ax=None, title: str | None = None):
    """``ANEES_k`` of each score (log scale) with the chi2 acceptance band for ``M`` runs;
    ``median_of`` adds the median NEES of other scores (dashed) and the chi2(nx) median line."""
    from adaptfilt.style import policy_label

    fig, ax = _ax(ax)
    for n, s in scores.items():
        k = np.arange(1, s.anees_k.size + 1)
        ax.semilogy(k, s.anees_k, label=f"{policy_label(n)}: ANEES")
    M = next(iter(scores.values())).nees.shape[0]
    for n, s in (median_of or {}).items():
        k = np.arange(1, s.anees_k.size + 1)
        ax.semilogy(k, np.median(s.nees, axis=0), ls="--", label=f"{policy_label(n)}: median NEES")
    lo, hi = metrics.chi2_bounds(nx, M, level)
    ax.axhspan(lo, hi, color="grey", alpha=0.35, lw=0, label=f"{level:.0%} $\\chi^2$ band of ANEES, M = {M}")
    if median_of:
        ax.axhline(chi2_median(nx), color="k", ls=":", lw=1, label=rf"median of $\chi^2_{{{nx}}}$ = {chi2_median(nx):.3f}")
    ax.set(xlabel="time step $k$", ylabel=r"ANEES$_k$ / median NEES", title=title or f"consistency (ideal ANEES = {nx})")
    ax.legend(ncol=2, loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below the axes: the curves fill them
    return fig


def plot_per_run_rmse(scores: Mapping[str, Score], bins=None, ax=None, title: str = ""):
    """Histograms (log x) of the per-run RMS errors, with each filter's median in the legend."""
    from adaptfilt.style import policy_label

    fig, ax = _ax(ax)
    bins = np.logspace(-1.5, 1.7, 50) if bins is None else bins
    for n, s in scores.items():
        ax.hist(s.run_rmse, bins=bins, histtype="step", lw=1.5, label=f"{policy_label(n)} (median {s.median_run_rmse:.2f})")
    ax.set(xscale="log", xlabel="per-run RMSE (over the run's steps)", ylabel="runs", title=title)
    ax.legend()
    return fig


def line_of_sight_errors(x: np.ndarray, mean: np.ndarray, pos: Sequence[int] = (0, 2)) -> tuple[np.ndarray, np.ndarray]:
    r"""Position errors split along and across the line of sight from the origin, ``(M, T)`` each.

    With the true position :math:`\mathbf p` and :math:`\mathbf u = \mathbf p/\|\mathbf p\|`,
    the radial (range) error is :math:`\mathbf e^T\mathbf u` and the cross-range
    error :math:`\mathbf e^T\mathbf u_\perp`, :math:`\mathbf u_\perp = [-u_2, u_1]`.
    """
    p = np.asarray(x, dtype=float)[..., list(pos)]
    e = p - np.asarray(mean, dtype=float)[..., list(pos)]
    norm = np.linalg.norm(p, axis=-1, keepdims=True)
    if (norm == 0).any():
        raise ValueError("a true position is at the origin: the line of sight is undefined there")
    u = p / norm
    return (e * u).sum(-1), e[..., 1] * u[..., 0] - e[..., 0] * u[..., 1]


def plot_line_of_sight_errors(radial: np.ndarray, cross: np.ndarray, ax=None, unit: str = "m"):
    """RMS over runs of the radial and cross-range position errors against time."""
    fig, ax = _ax(ax)
    k = np.arange(1, radial.shape[1] + 1)
    ax.plot(k, np.sqrt((radial ** 2).mean(0)), label="along the line of sight (range)")
    ax.plot(k, np.sqrt((cross ** 2).mean(0)), label="across the line of sight")
    ax.set(xlabel=r"time step $k$ ($\Delta t$ = 1 s)", ylabel=f"RMS position error ({unit})", ylim=(0, None),
           title="CTM, UKF: the error lies along the line of sight")
    ax.legend()
    return fig


# ======================================================================== chapter 3
def phi_brr(model, grid: np.ndarray, s: np.ndarray, z_next: np.ndarray, t: int) -> np.ndarray:
    r"""The information-state dynamics :math:`\mathbf s_{k+1} = \Phi_\mathrm{BRR}(\mathbf s_k, \mathbf z_{k+1})` (eq. (10))
    on a grid, batched over runs: ``s (N, M)`` at step ``t`` -> ``(N, M)`` at ``t + 1``.

    Chapman-Kolmogorov (3b) then Bayes (3a), as in
    :class:`~adaptfilt.exact.PointMassFilter`. Note the arguments: no estimate.
    """
    dx = grid[1] - grid[0]
    Q, R = float(model.Q[0, 0]), float(model.R[0, 0])
    transition = _gauss(grid[:, None] - model.f(grid[:, None], t + 1).T, Q) * dx   # p(x_{k+1} | x_k) on the grid
    pred = transition @ s                                                           # (3b)
    post = _gauss(z_next[None, :] - model.h(grid[:, None], t + 2), R) * pred        # (3a), unnormalised
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
    prior = np.repeat(_gauss(grid - model.m0[0], float(model.P0[0, 0]))[:, None], M, axis=1)
    post = _gauss(zz[None, :, 0] - model.h(grid[:, None], 1), float(model.R[0, 0])) * prior
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


# ======================================================================== chapter 4
def innovation_spread(env, n_runs: int = 3, steps: int = 5, rng: int = 0) -> str:
    """After ``steps`` default steps of ``env``: per run, the smallest and largest innovation
    over the parameter grid and the default-parameter innovation feature (a text table)."""
    d = env.reset(n_runs=n_runs, rng=np.random.default_rng(rng))
    for _ in range(steps):
        d, _, _, _ = env.step(np.full(d.n_runs, d.default_index))
    innov = d.candidates()["update"].innovation.reshape(env.nz, env.grid.size, d.n_runs)[0]  # (G, M)
    name = env.filt.rule.param_name
    lines = [f"innovation at k = {d.t + 1} for {name} = {env.grid.min():g} .. {env.grid.max():g}:"]
    for r in range(d.n_runs):
        lines.append(f"  run {r}: min {innov[:, r].min():+.4f}  max {innov[:, r].max():+.4f}   "
                     f"default-{name} feature {d.features[r, -1]:+.4f}")
    return "\n".join(lines)


def kappa_sweep(model, values: Sequence[float], n_runs: int, seed: int = 0):
    """Fixed update ``kappa`` (predict at the default) on the same trajectories:
    :func:`~adaptfilt.evaluation.evaluate` of one :class:`~adaptfilt.policies.FixedPolicy` per value."""
    from adaptfilt.evaluation import evaluate
    from adaptfilt.gaf import UKF
    from adaptfilt.mdp import Cost, FilterEnv
    from adaptfilt.policies import FixedPolicy

    env = FilterEnv(UKF(model, on_indefinite="clip"), values, cost=Cost("nis"))
    return evaluate(env, [FixedPolicy(v, "kappa", grid=values) for v in values], n_runs=n_runs, seed=seed,
                    progress=False)


def plot_sweep(res, values: Sequence[float], title: str, nx: int, log_anees: bool = True, unit: str | None = None):
    """Time-averaged RMSE and ANEES (95 % CIs) of a :func:`kappa_sweep` against ``kappa`` (symlog axis);
    ``unit`` (e.g. ``"m"``) labels the RMSE axis."""
    from adaptfilt import style

    fig, axes = style.figure(1, 2)
    rmse_label = "time-averaged RMSE" + (f" ({unit})" if unit else "")
    for ax, key, lab in [(axes[0], "rmse", rmse_label), (axes[1], "anees", "time-averaged ANEES")]:
        v = np.array([getattr(res[n], key) for n in res.names])
        ci = np.array([getattr(res[n], key + "_ci") for n in res.names])
        ax.errorbar(values, v, yerr=[v - ci[:, 0], ci[:, 1] - v], fmt="o-", ms=3, capsize=2, lw=1)
        ax.set_xscale("symlog", linthresh=1)
        ax.set(xlabel=f"fixed update {style.param_label('kappa')}", ylabel=lab, title=f"{title}: {lab.split()[1]}")
    if log_anees:
        axes[1].set_yscale("log")
    axes[1].axhline(nx, color="0.4", ls="--", lw=0.8, label=f"ideal = $n_x$ = {nx}")
    axes[1].legend()
    return fig


def results_lines(res, names: Sequence[str] | None = None) -> str:
    """One line per policy of an evaluation: time-averaged RMSE and ANEES with their 95 % CIs."""
    names = res.names if names is None else list(names)
    w = max(len(n) for n in names)
    return "\n".join(f"{n:<{w}}  RMSE {p.rmse:.3g} [{p.rmse_ci[0]:.3g}, {p.rmse_ci[1]:.3g}]   "
                     f"ANEES {p.anees:.3g} [{p.anees_ci[0]:.3g}, {p.anees_ci[1]:.3g}]"
                     for n, p in ((n, res[n]) for n in names))


def cost_samples(env, policies: Sequence, traj) -> dict[str, np.ndarray]:
    """One-step costs of each policy over all (run, step) pairs of ``traj``, flattened."""
    from adaptfilt.mdp import rollout

    return {p.name: rollout(env, p, traj=traj)[1].ravel() for p in policies}


def cost_summary(costs: Mapping[str, np.ndarray]) -> str:
    """Median, mean, 99.9 % quantile, maximum and the share of the total carried by the top 1 % of steps."""
    w = max(len(n) for n in costs)
    lines = []
    for n, c in costs.items():
        q = np.quantile(c, [0.5, 0.999])
        top = np.sort(c)[::-1][: max(1, c.size // 100)].sum() / c.sum()
        lines.append(f"{n:<{w}}  median {q[0]:.3g}  mean {c.mean():.3g}  99.9% quantile {q[1]:.3g}  "
                     f"max {c.max():.3g}  top 1% of steps carry {top:.0%} of the total")
    return "\n".join(lines)


def plot_cost_distribution(costs: Mapping[str, np.ndarray], floor: float = 1e-8, title: str = ""):
    """Densities of ``log10`` one-step costs (costs below ``floor`` drawn at it), dashed: each mean."""
    from adaptfilt.style import figure, policy_label

    fig, ax = figure()
    bins = np.linspace(np.log10(floor), 8, 81)
    for n, c in costs.items():
        line = ax.hist(np.log10(np.maximum(c, floor)), bins=bins, histtype="step", lw=1.5, density=True,
                       label=policy_label(n))[2][0]
        ax.axvline(np.log10(c.mean()), color=line.get_edgecolor(), ls="--", lw=1)
    ax.set_yscale("log")
    ax.set(xlabel=rf"$\log_{{10}}\bar L_\mathrm{{NIS}}$ (one step; costs below $10^{{{np.log10(floor):.0f}}}$ drawn there)",
           ylabel="density (log scale)", title=title)
    ax.legend()
    return fig
