"""What chapter 17 (Adaptive particle count) draws: the exact posterior beside a Gaussian, every run's error
sorted, and KLD-sampling's count over one run. The study itself is :mod:`adaptfilt.experiments.particles_study`."""
from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy import stats

from adaptfilt import metrics
from adaptfilt.course.common import figure_axes

__all__ = ["separated_modes", "plot_two_modes", "plot_run_errors", "plot_kld_run", "study_protocol"]


def separated_modes(density: Mapping[int, np.ndarray], grid: np.ndarray, gap: float = 3.0) -> np.ndarray:
    """``(M, T)``: per run and step, the smaller of the posterior masses below ``-gap`` and above ``+gap``
    (``density``: step -> ``(M, len(grid))`` densities of a scalar state, as
    :class:`~adaptfilt.exact.PointMassFilter` keeps them). 0 for one mode, 0.5 for two equal modes at
    ``+-x`` with ``|x| > gap``; a single mode on zero counts as one."""
    dx = float(grid[1] - grid[0])
    lo, hi = grid < -gap, grid > gap
    return np.stack([np.minimum(d[:, lo].sum(1), d[:, hi].sum(1)) * dx for _, d in sorted(density.items())], axis=1)


def plot_two_modes(grid: np.ndarray, posterior: np.ndarray, mean: float, var: float, x_true: float, ax=None,
                   title: str | None = None):
    """The exact posterior density on ``grid`` beside the Gaussian ``N(mean, var)`` and the true state."""
    _, ax = figure_axes(ax)
    ax.plot(grid, posterior, label="exact posterior (point-mass)")
    ax.plot(grid, stats.norm.pdf(grid, mean, np.sqrt(var)), label="the UKF's Gaussian")
    ax.axvline(x_true, color="k", ls=":", label="true state")
    ax.set(xlim=(-25, 25), xlabel="$x_k$", ylabel="density", title=title)
    ax.legend(fontsize="small")
    return ax


def plot_run_errors(x: np.ndarray, runs: Mapping[str, object], ax=None, title: str | None = None):
    """Every run's RMS error over its steps, sorted (an empirical CDF, log axis), one line per filter run."""
    _, ax = figure_axes(ax)
    for name, run in runs.items():
        e = np.sort(np.sqrt(metrics.squared_error(x, run.mean).mean(axis=1)))
        ax.plot(e, np.arange(1, e.size + 1) / e.size, label=name)
    ax.set(xscale="log", xlabel="RMS error of a run (log axis)", ylabel="share of runs", title=title)
    ax.legend(fontsize="small")
    return ax


def plot_kld_run(counts: np.ndarray, x: np.ndarray, two_modes: np.ndarray, ax=None, title: str | None = None):
    """One run: the particle count per step (``counts (T,)``), the state ``x (T,)`` on a second axis, and the
    steps whose exact posterior has two separated modes (``two_modes (T,)`` bool) shaded."""
    _, ax = figure_axes(ax, size=(12, 3.6))
    k = np.arange(1, counts.size + 1)
    ax.plot(k, counts, drawstyle="steps-mid", label="KLD-sampling's $N_k$")
    ax.set(xlabel="step $k$", ylabel="particles", ylim=(0, None), title=title)
    ax2 = ax.twinx()
    ax2.plot(k, x, color="C1", lw=1, label="$x_k$")
    ax2.fill_between(k, -20, 20, where=two_modes, color="0.85", step="mid", label="two separated modes")
    ax2.set(ylim=(-20, 20), ylabel="$x_k$")
    ax.figure.legend(loc="outside lower center", ncol=3, fontsize="small")
    return ax


def study_protocol(experiments, root=None) -> str:
    """How the particle study was made, read from what it stored: per experiment, the number of
    evaluation runs (``results.json``) and the learned seeds' training command (``data/beyond/manifest.json``,
    the seed left out), so that the chapter's prose can quote both from an output."""
    import re

    from adaptfilt.experiments import artefacts

    base = artefacts.data_dir() if root is None else root
    files = artefacts.manifest(f"{base}/beyond")["files"]
    lines = []
    for e in experiments:
        n_runs = artefacts.load_beyond_results(f"particles-{e}", root).config["n_runs"]
        cmds = [f["command"] for f in files if f["path"].startswith(f"policies/{e}-adaptive-s")]
        recipe = {re.sub(r" --seed \d+ --out \S+", "", c) for c in cmds}
        lines.append(f"{e}: evaluated on {n_runs} runs; {len(cmds)} learned seeds, each `{' | '.join(sorted(recipe))}`")
    return "\n".join(lines)
