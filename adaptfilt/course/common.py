r"""What every chapter of the course uses: :func:`show_source` (a chapter shows the code that *is* the
lesson), the per-step RMSE with a bootstrap band over runs (:class:`Score`, :func:`score`,
:func:`score_table`, :func:`paired_rmse_difference`, :func:`plot_rmse_k`) and :func:`chi2_median`.

The chapters' helpers: :mod:`adaptfilt.course.bayes` (1), :mod:`adaptfilt.course.moments` and :mod:`adaptfilt.course.plain_filter` (2),
:mod:`adaptfilt.course.myopia` (3), :mod:`adaptfilt.course.adaptation` (4). Arrays follow the
library's public layout: runs first, ``(M, T, ...)``; a grid density is ``(N,)`` for one run and
``(M, T, N)`` for all of them. Figures use :mod:`adaptfilt.style`.
"""
from __future__ import annotations

import inspect
import textwrap
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from adaptfilt import metrics

__all__ = ["show_source", "Score", "score", "score_table", "paired_rmse_difference", "chi2_median", "plot_rmse_k"]


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


def pyplot():
    import matplotlib.pyplot as plt

    return plt


def figure_axes(ax, **figure_kw):
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
    :class:`~adaptfilt.filters.FilterRun`); ``counts`` are bootstrap resampling
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

    fig, ax = figure_axes(ax)
    for i, (n, s) in enumerate(scores.items()):
        c = None if colors is None else colors[i]
        k = np.arange(1, s.rmse_k.size + 1)
        line, = ax.plot(k, s.rmse_k, color=c, label=policy_label(n))
        ax.fill_between(k, *s.rmse_band, color=line.get_color(), alpha=0.2, lw=0)
    ax.set(xlabel="time step $k$", ylabel=r"RMSE$_k$", title=title or "RMSE over time (95 % bootstrap bands)")
    ax.set_ylim(0, None)
    ax.legend()
    return fig
