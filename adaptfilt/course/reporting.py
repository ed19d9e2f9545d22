r"""Chapter 5, "How results are reported": the statistics behind every verdict of the course, on stored results.

The library computes the intervals (:mod:`adaptfilt.metrics`, :mod:`adaptfilt.seed_stats`,
:meth:`adaptfilt.results.Results.paired_difference`); this module takes them apart for the reader:

* :func:`run_counts` -- the multinomial resampling counts an evaluation used for its run-level
  bootstrap, so that a chapter can recompute a stored replicate from the per-run values;
* :func:`unpaired` -- the replicates of a difference as if the two policies had been resampled
  independently (what pairing saves);
* :func:`pooled_runs` -- the interval that forgets the training seed (every seed's runs pooled);
* :func:`divergence` -- the share of diverged runs (:func:`adaptfilt.metrics.divergent`) with its
  interval, and the ANEES with and without them;
* the chapter's figures: :func:`plot_bootstrap`, :func:`plot_paired`, :func:`plot_levels`,
  :func:`plot_divergence`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from adaptfilt import metrics, seed_stats
from adaptfilt.course.common import figure_axes

__all__ = ["run_counts", "unpaired", "pooled_runs", "divergence", "plot_bootstrap", "plot_paired", "plot_levels",
           "plot_divergence"]


def run_counts(results) -> np.ndarray:
    """``(n_boot, M)``, read-only: the resampling counts :func:`adaptfilt.evaluation.evaluate` drew for ``results``
    (replicate ``b`` takes run ``l`` ``counts[b, l]`` times; the same counts for every policy).

    ``counts @ run_cost / M`` is the stored ``boot_cost`` of every policy of ``results``."""
    from adaptfilt.runs import bootstrap_counts

    c = results.config
    if c.get("trajectories") == "given":
        raise ValueError("these results were evaluated on given trajectories: their counts are not derivable from the seed")
    return bootstrap_counts(int(c["n_runs"]), int(c["n_boot"]), int(c["seed"]))


def unpaired(boot_a: np.ndarray, boot_b: np.ndarray, seed: int = 0) -> np.ndarray:
    """Replicates of ``a - b`` as if ``a`` and ``b`` had been resampled independently.

    Replicate ``b`` of every policy uses the same run counts; pairing ``a``'s replicate ``i`` with
    ``b``'s replicate ``perm[i]`` pairs two independent resamples instead, which is what two
    evaluations on different trajectories would give (up to the common trajectories' mean)."""
    boot_a, boot_b = np.asarray(boot_a, float), np.asarray(boot_b, float)
    if boot_a.shape != boot_b.shape:
        raise ValueError(f"replicates of different shapes: {boot_a.shape} and {boot_b.shape}")
    return boot_a - np.random.default_rng(seed).permutation(boot_b)


def pooled_runs(results, names: Sequence[str], metric: str = "rmse") -> np.ndarray:
    """Replicates of the mean over the seeds ``names`` that resample the runs only (every seed at
    run-resample ``b``): the interval of "these eight policies on other trajectories", which
    forgets that another training seed gives another policy. Compare with
    :func:`adaptfilt.seed_stats.aggregate`, which resamples the seeds too."""
    return np.mean([np.asarray(getattr(results[n], "boot_" + metric), float) for n in names], axis=0)


def divergence(results, name: str, level: float = 0.95) -> dict:
    """The diverged runs of policy ``name`` by the library's one definition
    (:func:`adaptfilt.metrics.divergent`: time-averaged NEES above ``DIVERGED_NEES * nx``), from the
    stored per-run time-averaged NEES: ``{"n", "runs", "rate", "ci", "anees", "anees_kept", "median"}``
    (the ANEES over all runs, over the runs that did not diverge, and the median run's NEES)."""
    p, nx = results[name], int(results.config["nx"])
    run = np.asarray(p.run_anees, float)
    if run.size == 0:
        raise ValueError(f"{name}: these results were stored without per-run values (run_anees)")
    bad = metrics.divergent(run[:, None], nx)  # one column: its time average is the run's own
    rate, lo, hi = metrics.rate_ci(int(bad.sum()), bad.size, level)
    return {"n": int(bad.sum()), "runs": int(bad.size), "rate": rate, "ci": (lo, hi), "anees": float(run.mean()),
            "anees_kept": float(run[~bad].mean()), "median": float(np.median(run)), "bad": bad}


# ------------------------------------------------------------------ figures
def _interval(ax, y, v, lo, hi, **kw):
    ax.errorbar(v, y, xerr=[[v - lo], [hi - v]], capsize=3, **kw)


def plot_bootstrap(per_run: np.ndarray, boot: np.ndarray, level: float = 0.95, label: str = "mean NIS cost", axes=None):
    """Left: the per-run values (skewed: a long right tail). Right: the bootstrap replicates of their mean
    with the percentile interval and the normal approximation's interval beside it."""
    from adaptfilt import style

    fig, axes = (axes[0].figure, axes) if axes is not None else style.figure(1, 2, size=(11, 3.8))
    per_run = np.asarray(per_run, float)
    axes[0].hist(per_run, bins=80, color="0.6")
    axes[0].axvline(per_run.mean(), color="black", lw=1.2, label=f"mean {per_run.mean():.3f}")
    axes[0].set(xlabel=f"{label} of one run", ylabel="runs", title=f"{per_run.size} runs")
    axes[0].legend(loc="upper right", frameon=False)
    axes[1].hist(boot, bins=40, color=style.OKABE_ITO[0], alpha=0.7)
    lo, hi = metrics.percentile_ci(boot, level)
    _, nlo, nhi = metrics.mean_ci(per_run, level)
    for x, ls, lab in ((lo, "-", "percentile interval"), (hi, "-", None), (nlo, ":", "mean ± 1.96 SE"), (nhi, ":", None)):
        axes[1].axvline(x, color="black", ls=ls, lw=1.2, label=lab)
    axes[1].set(xlabel=f"{label}: bootstrap replicates of the mean", ylabel="replicates", title=f"{boot.size} replicates")
    axes[1].legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    return fig


def plot_paired(results, a: str, b: str, metric: str = "rmse", seed: int = 0, axes=None):
    """Left: per-run values of ``a`` against ``b`` on the same runs. Right: the replicates of
    ``a - b``, paired (same run counts) and unpaired (:func:`unpaired`), with their intervals."""
    from adaptfilt import style

    fig, axes = (axes[0].figure, axes) if axes is not None else style.figure(1, 2, size=(11, 4.2))
    ra, rb = (np.asarray(getattr(results[n], "run_" + metric), float) for n in (a, b))
    axes[0].scatter(rb, ra, s=2, alpha=0.25, color="0.35", rasterized=True)
    lim = [min(ra.min(), rb.min()), max(ra.max(), rb.max())]
    axes[0].plot(lim, lim, color=style.OKABE_ITO[3], lw=1)
    axes[0].set(xlabel=f"{style.policy_label(b)}: {metric} of one run",
                ylabel=f"{style.policy_label(a)}: same run",
                title=f"same runs: correlation {np.corrcoef(ra, rb)[0, 1]:.2f}")
    ba, bb = (np.asarray(getattr(results[n], "boot_" + metric), float) for n in (a, b))
    reps = {"paired": ba - bb, "unpaired": unpaired(ba, bb, seed)}
    # common bins and outline (step) histograms: the narrower paired histogram would otherwise
    # disappear under the filled unpaired one; the interval lines differ in style, not only colour
    bins = np.histogram_bin_edges(np.concatenate(list(reps.values())), bins=50)
    for (lab, r), col, ls in zip(reps.items(), (style.OKABE_ITO[0], style.OKABE_ITO[1]), ("-", "--")):
        lo, hi = metrics.percentile_ci(r)
        axes[1].hist(r, bins=bins, histtype="step", lw=2, ls=ls, color=col, label=f"{lab} [{lo:+.3f}, {hi:+.3f}]",
                     zorder=3 if lab == "paired" else 2)
        for x in (lo, hi):
            axes[1].axvline(x, color=col, ls=ls, lw=1.5, zorder=3 if lab == "paired" else 2)
    axes[1].axvline(0, color="black", lw=0.8)
    axes[1].set(xlabel=f"{metric}: {style.policy_label(a)} − {style.policy_label(b)}", ylabel="replicates")
    axes[1].legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False, title="95 % interval")
    return fig


def plot_levels(results, names: Sequence[str], metric: str = "rmse", ax=None):
    """Each seed's run-level interval, the pooled-runs interval of their mean (:func:`pooled_runs`,
    seeds fixed) and the two-level intervals of the mean and the IQM (seeds resampled too)."""
    from adaptfilt import style

    fig, ax = figure_axes(ax, size=(9, 4.6))
    for i, n in enumerate(names):
        p = results[n]
        _interval(ax, i, getattr(p, metric), *getattr(p, metric + "_ci"), fmt="o", ms=4, color="0.4")
    agg = seed_stats.aggregate(results, names, metric)
    pooled = metrics.percentile_ci(pooled_runs(results, names, metric))
    rows = [("mean, runs resampled only", agg.mean, pooled, style.OKABE_ITO[3], "s"),
            ("mean, seeds x runs", agg.mean, agg.mean_ci, style.OKABE_ITO[0], "s"),
            ("IQM, seeds x runs", agg.iqm, agg.iqm_ci, style.OKABE_ITO[2], "D")]
    for j, (lab, v, (lo, hi), col, mk) in enumerate(rows):
        _interval(ax, len(names) + 1 + j, v, lo, hi, fmt=mk, ms=6, color=col, mec="black", lw=2)
    ax.set_yticks(list(range(len(names))) + [len(names) + 1 + j for j in range(len(rows))],
                  list(names) + [r[0] for r in rows])
    ax.invert_yaxis()
    ax.set_xlabel(f"time-averaged {metric.upper() if metric in ('rmse', 'anees') else metric} (95 % intervals)")
    return fig


def plot_divergence(results, names: Sequence[str], ax=None):
    """Histogram of the per-run time-averaged NEES divided by ``nx`` (log axis) for ``names``, with the
    divergence threshold ``DIVERGED_NEES`` (:func:`adaptfilt.metrics.divergent`)."""
    from adaptfilt import style

    fig, ax = figure_axes(ax, size=(10, 4))
    nx = int(results.config["nx"])
    runs = [np.asarray(results[n].run_anees, float) / nx for n in names]
    bins = np.geomspace(min(r.min() for r in runs), max(r.max() for r in runs), 80)
    for r, n, col in zip(runs, names, style.colors(len(names))):
        # the policy's own name, as the chapters print it in their tables and prose
        ax.hist(r, bins=bins, histtype="step", lw=1.5, color=col, label=n)
    ax.axvline(metrics.DIVERGED_NEES, color="black", ls="--", lw=1.2, label=r"diverged: NEES $> 10^4\,n_x$")
    ax.set(xscale="log", yscale="log", xlabel=r"time-averaged NEES of one run / $n_x$", ylabel="runs")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    return fig
